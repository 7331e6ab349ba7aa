//! `stcvae generate`: datasets of unit-sphere walks.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use scatter_sim::conditions::{ConditionSampler, Conditions};
use scatter_sim::dataset::{self, DatasetError, GenerateSpec, Header, Shard};
use serde::Deserialize;

use crate::{interrupt, progress};

/// The paper-sized dataset: 2^22 walks.
pub const DEFAULT_WALKS: u64 = 1 << 22;
/// Where a whole run goes without --out: the training set `train`'s default config reads.
const DEFAULT_OUT: &str = "data/train.bin";
/// Walks in fixed-condition mode when --samples is not given.
const DEFAULT_FIXED_WALKS: u64 = 10_000;

#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    stcvae generate --config configs/dataset/default.toml --out data/train.bin\n  \
    stcvae generate --samples 10000 --tau 5 --g 0.4 --albedo 1.0 --seed 7 --out walks.csv\n  \
    stcvae generate --config configs/dataset/default.toml --shard 3/8 --out data/train-3.bin")]
pub struct Args {
    /// Dataset config (TOML: walks, seed, `[conditions]`); default: the authors' distribution
    /// with 2^22 walks.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output file: `.csv` writes CSV, anything else the binary dataset format. Default
    /// data/train.bin (the training set `train` reads) for a whole run of a config or of
    /// the default distribution; fixed-condition mode and --shard need one.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Number of walks of the whole run (overrides the config; in fixed-condition mode,
    /// default 10,000; at least 1).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::whole::whole::<u64>(1, u64::MAX))]
    samples: Option<u64>,
    /// Fixed-condition mode: optical radius τ of every walk, in [0, 1000] (needs --g and
    /// --albedo).
    #[arg(long, requires_all = ["g", "albedo"], allow_hyphen_values = true)]
    tau: Option<f64>,
    /// Fixed-condition mode: Henyey–Greenstein g in [-0.999, 0.999].
    #[arg(long, requires_all = ["tau", "albedo"], allow_hyphen_values = true)]
    g: Option<f64>,
    /// Fixed-condition mode: single-scattering albedo in [0, 1].
    #[arg(long, requires_all = ["tau", "g"], allow_hyphen_values = true)]
    albedo: Option<f64>,
    /// Random seed (overrides the config; default 1).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::render::parse_seed)]
    seed: Option<u64>,
    /// Write only shard i of n (e.g. 3/8): disjoint pieces that `stcvae merge` joins into
    /// exactly the unsharded run (binary shards, in any order; CSV rows carry no walk
    /// number, so CSV shards are joined in the order given: list them 0, 1, …, n − 1).
    #[arg(long, allow_hyphen_values = true)]
    shard: Option<Shard>,
    /// Worker threads, 1 to 1,024 (default: RAYON_NUM_THREADS where set, else all cores). The output does not depend on it.
    #[arg(long, value_parser = crate::generate::threads_parser())]
    threads: Option<usize>,
}

/// A dataset config file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetConfig {
    #[serde(deserialize_with = "at_least_one")]
    pub walks: u64,
    #[serde(default = "default_seed")]
    pub seed: u64,
    #[serde(default)]
    pub conditions: ConditionSampler,
}

fn default_seed() -> u64 {
    1
}

/// A config's whole number of at least 1 (`walks`, `checkpoint_every`): -1 is refused with
/// the range that 0 is refused by, not serde's "[0, 2^64)".
pub fn at_least_one<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<u64, D::Error> {
    scatter_sim::ranges::whole_in(d, 1, u64::MAX)
}

pub fn load_config(path: &Path) -> Result<DatasetConfig> {
    let text = scatter_sim::output::read_input_to_string(path)
        .with_context(|| format!("cannot read dataset config {}", path.display()))?;
    wrong_kind(path, &text, render_gpu::scene::ConfigKind::Dataset)?;
    let cfg: DatasetConfig = parse_toml(path, &text)?;
    if cfg.walks == 0 {
        // Worded as -1's refusal is (`at_least_one`).
        bail!(
            "{}: walks = 0 is out of range: allowed {}",
            path.display(),
            scatter_sim::ranges::whole_range(1, u64::MAX)
        );
    }
    cfg.conditions
        .validate()
        .map_err(|e| anyhow::anyhow!("{}: conditions.{e}", path.display()))?;
    Ok(cfg)
}

/// Refuses another command's file (a scene given to `generate --config`, say), naming what
/// it is, where the parser would name its first unknown key.
pub fn wrong_kind(path: &Path, text: &str, want: render_gpu::scene::ConfigKind) -> Result<()> {
    if let Some(k) = render_gpu::scene::config_kind(text).filter(|k| *k != want) {
        bail!(
            "{}: {}, not {}",
            path.display(),
            k.describe(),
            want.describe()
        );
    }
    Ok(())
}

/// Parses a TOML config into `T`, with a one-line error naming the file, line and
/// column (toml's own message spans several lines).
pub fn parse_toml<T: serde::de::DeserializeOwned>(path: &Path, text: &str) -> Result<T> {
    toml::from_str(text)
        .map_err(|e| anyhow::anyhow!(render_gpu::scene::describe_toml_error(path, text, &e)))
}

/// The range of `--threads` wherever it is offered: beyond ~1,000 threads the OS runs out
/// of processes or stack memory long before the work speeds up.
pub fn threads_parser() -> impl Fn(&str) -> Result<usize, String> + Clone + Send + Sync {
    crate::whole::whole(1, MAX_THREADS as u64)
}

const MAX_THREADS: usize = 1024;

/// A rayon pool with `threads` workers (all cores when `None`; `--threads` values come
/// through [`threads_parser`], which keeps them in range).
pub fn pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        b = b.num_threads(t);
    }
    b.build().map_err(|e| {
        anyhow::anyhow!(
            "could not start {} worker threads: {e}",
            threads.map_or("the".to_string(), |t| t.to_string())
        )
    })
}

/// Generates the dataset of a config file (used by `train` when its dataset is missing).
pub fn generate_from_config(config: &Path, out: &Path) -> Result<()> {
    run(Args {
        config: Some(config.to_path_buf()),
        out: Some(out.to_path_buf()),
        samples: None,
        tau: None,
        g: None,
        albedo: None,
        seed: None,
        shard: None,
        threads: None,
    })
}

pub fn run(a: Args) -> Result<()> {
    let (spec, fixed) = spec_of(&a)?;
    let out = out_path(&a, fixed)?;
    // First, so that a Ctrl-C from here on stops cleanly.
    let cancel = interrupt::flag();
    crate::check_out("--out", &out)?;
    let inputs: Vec<(String, PathBuf)> = a
        .config
        .iter()
        .map(|c| ("--config".to_string(), c.clone()))
        .collect();
    crate::paths::check_not_input("--out", &out, &inputs)?;
    crate::paths::check_dataset_out(
        &out,
        "a dataset (.csv for text, any other name binary, e.g. .bin)",
    )?;
    let piece = spec.piece();
    if piece.count == 0 {
        eprintln!(
            "warning: shard {}/{} of a run of {} holds no walk (more shards than walks): \
             the file has no rows",
            spec.shard.index,
            spec.shard.count,
            progress::count(spec.total_walks, "walk")
        );
    }
    // What sets the count: `train` generates from its dataset_config alone, and has no
    // --samples to lower.
    let lower = match (&a.config, a.samples) {
        (Some(c), None) => format!("walks in {}", crate::paths::shown(c)),
        _ => "--samples".to_string(),
    };
    crate::paths::check_room(&out, piece.count, &lower)?;
    let pool = pool(a.threads)?;
    eprintln!(
        "generating {}{} ({} mode, seed {}, {}) -> {}",
        progress::count(piece.count, "walk"),
        if spec.shard == Shard::WHOLE {
            String::new()
        } else {
            format!(
                " (shard {}/{}: walks {}..{} of {})",
                spec.shard.index,
                spec.shard.count,
                piece.first_walk,
                piece.first_walk + piece.count,
                spec.total_walks
            )
        },
        if fixed {
            "fixed-condition"
        } else {
            "sampled-condition"
        },
        spec.seed,
        progress::count(pool.current_num_threads() as u64, "thread"),
        crate::paths::shown(&out)
    );
    let mut sink = dataset::create_sink(&out, Header::new(vec![piece.clone()]))?;
    let pb = progress::bar(piece.count, "walks");
    let start = Instant::now();
    let summary = pool.install(|| {
        dataset::generate(&spec, sink.as_mut(), cancel, &mut |s| {
            pb.set_position(s.walks);
            let secs = start.elapsed().as_secs_f64().max(1e-9);
            pb.set_message(format!("{} events/s", progress::si(s.events as f64 / secs)));
        })
    });
    pb.finish_and_clear();
    let summary = summary.map_err(|e| match e {
        DatasetError::Interrupted => anyhow!("interrupted: nothing written to {}", out.display()),
        e => e.into(),
    })?;
    sink.finish()?;
    let secs = start.elapsed().as_secs_f64();
    eprintln!(
        "wrote {} to {} in {:.1} s: {} events ({} events/s, {:.1} per walk, max {})",
        progress::count(summary.walks as u64, "walk"),
        crate::paths::shown(&out),
        secs,
        summary.events,
        progress::si(summary.events as f64 / secs),
        summary.events as f64 / summary.walks.max(1) as f64,
        summary.max_events
    );
    Ok(())
}

/// What to generate: the fixed conditions or the config's (the authors' distribution by
/// default), with the command line's walks, seed and shard; and whether the conditions are
/// fixed.
fn spec_of(a: &Args) -> Result<(GenerateSpec, bool)> {
    let (mut spec, fixed) = match (a.tau, a.g, a.albedo) {
        (Some(tau), Some(g), Some(albedo)) => {
            if a.config.is_some() {
                bail!("--config and --tau/--g/--albedo are exclusive: choose one");
            }
            let c = Conditions { tau, g, albedo };
            c.validate().map_err(|e| anyhow::anyhow!("--{e}"))?;
            (
                GenerateSpec {
                    seed: 1,
                    sampler: ConditionSampler::fixed(c),
                    total_walks: DEFAULT_FIXED_WALKS,
                    shard: Shard::WHOLE,
                },
                true,
            )
        }
        _ => {
            let cfg = match &a.config {
                Some(p) => load_config(p)?,
                None => DatasetConfig {
                    walks: DEFAULT_WALKS,
                    seed: default_seed(),
                    conditions: ConditionSampler::authors(),
                },
            };
            (
                GenerateSpec {
                    seed: cfg.seed,
                    sampler: cfg.conditions,
                    total_walks: cfg.walks,
                    shard: Shard::WHOLE,
                },
                false,
            )
        }
    };
    if let Some(n) = a.samples {
        spec.total_walks = n;
    }
    if let Some(s) = a.seed {
        spec.seed = s;
    }
    if let Some(s) = a.shard {
        spec.shard = s;
    }
    if spec.total_walks == 0 {
        bail!("the number of walks must be at least 1");
    }
    Ok((spec, fixed))
}

/// The output file: `--out`, or the training set's default where that cannot be a mistake.
fn out_path(a: &Args, fixed: bool) -> Result<PathBuf> {
    // A default of data/train.bin there replaced the training set without a word (and
    // `train` then trained on 10,000 walks of one medium).
    Ok(match (&a.out, fixed, a.shard) {
        (Some(o), _, _) => o.clone(),
        (None, true, _) => bail!(
            "--out is needed in fixed-condition mode (--tau/--g/--albedo): the default, \
             {DEFAULT_OUT}, is the training set `stcvae train` reads"
        ),
        (None, false, Some(_)) => bail!(
            "--out is needed with --shard: each shard is a file of its own, joined by \
             `stcvae merge` (the default, {DEFAULT_OUT}, is the training set)"
        ),
        (None, false, None) => PathBuf::from(DEFAULT_OUT),
    })
}

#[cfg(test)]
mod tests {
    /// The shipped dataset config draws from the authors' distribution, which `generate`
    /// without a config uses too (`ConditionSampler::authors`): the two spellings of one
    /// distribution must not drift apart.
    #[test]
    fn the_default_dataset_config_is_the_authors_distribution() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/dataset/default.toml");
        let cfg = super::load_config(&path).unwrap();
        assert_eq!(
            cfg.conditions,
            scatter_sim::conditions::ConditionSampler::authors()
        );
        assert_eq!(cfg.seed, super::default_seed());
        assert_eq!(cfg.walks, super::DEFAULT_WALKS);
    }

    /// `generate`'s and `sample`'s help give τ's and g's ranges as the checks have them
    /// (clap's help is written as doc comments, which cannot name the constants).
    #[test]
    fn the_help_gives_the_checked_ranges() {
        use clap::CommandFactory as _;
        use scatter_sim::ranges::{G_RANGE, TAU_RANGE};
        #[derive(clap::Parser)]
        struct Generate {
            #[command(flatten)]
            a: super::Args,
        }
        #[derive(clap::Parser)]
        struct Sample {
            #[command(flatten)]
            a: crate::model_cmds::SampleArgs,
        }
        for cmd in [Generate::command(), Sample::command()] {
            let help = |id: &str| crate::help_of(&cmd, id);
            assert!(help("tau").contains(TAU_RANGE), "{}", help("tau"));
            assert!(help("g").contains(G_RANGE), "{}", help("g"));
        }
    }
}
