//! Parallel, deterministic dataset generation.
//!
//! Walk i of a run depends only on (seed, i) — its conditions and its path are drawn
//! from [`WalkRng::for_walk`] — so the rows are the same whatever the thread count, and
//! shard i/n is exactly the slice of the unsharded run. Rows are produced in chunks: each
//! chunk runs in parallel (rayon keeps the order), then streams to the sink, so memory
//! holds one chunk, never the table.

use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;

use super::{DatasetError, Piece, Row, RowSink};
use crate::conditions::{AlbedoSampler, ConditionSampler, GSampler, TauSampler};
use crate::rng::WalkRng;
use crate::walk::simulate_walk;

/// Walks per chunk: about a second of work on two cores for the authors' sampler, small
/// enough for a lively progress bar, large enough to keep both
/// cores busy despite the τ³ spread of walk lengths.
const CHUNK: u64 = 4096;

/// The i-th of n disjoint, contiguous pieces of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
}

impl Shard {
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// The walk indices of this shard of a run of `total` walks.
    pub fn range(&self, total: u64) -> Range<u64> {
        let at = |i: u64| ((i as u128 * total as u128) / self.count as u128) as u64;
        at(self.index)..at(self.index + 1)
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    /// Parses "i/n" with 0 ≤ i < n.
    fn from_str(s: &str) -> Result<Self, String> {
        let err = || format!("shard '{s}': expected i/n with 0 <= i < n, e.g. 0/4");
        let (i, n) = s.split_once('/').ok_or_else(err)?;
        let index: u64 = i.trim().parse().map_err(|_| err())?;
        let count: u64 = n.trim().parse().map_err(|_| err())?;
        if count == 0 || index >= count {
            return Err(err());
        }
        Ok(Shard { index, count })
    }
}

/// What to generate.
#[derive(Clone, Debug)]
pub struct GenerateSpec {
    pub seed: u64,
    pub sampler: ConditionSampler,
    pub total_walks: u64,
    pub shard: Shard,
}

impl GenerateSpec {
    pub fn range(&self) -> Range<u64> {
        self.shard.range(self.total_walks)
    }

    /// The provenance record of the rows this spec produces.
    pub fn piece(&self) -> Piece {
        let r = self.range();
        Piece {
            seed: self.seed,
            sampler: self.sampler.clone(),
            total_walks: self.total_walks,
            first_walk: r.start,
            count: r.end - r.start,
            simulator: Some(simulator_fingerprint().to_owned()),
        }
    }
}

/// This build's simulator, as 8 hex digits: the CRC-32 of the rows of fixed walks (10 ms at
/// most, once): 64 over moderate media (τ 0.5–12, |g| ≤ 0.95, φ 0.3–1), 16 from the
/// authors' distribution (its power laws), 8 isotropic ones at φ = 1 (the phase function's
/// and the reservoir's own branches) and 8 whose g is clamped to G_MAX. A review found the
/// default dataset's samplers and branches outside the first 64 alone. Anything that
/// changes a walk changes it: the walk, the phase function, the reservoir, the frames, the
/// random streams, a dependency's numbers, the platform's libm. Hashing the sources instead
/// would miss the last three and change with every comment. Datasets record it per piece,
/// so that shards of different builds are not merged unsaid, and `train`, whose held-out
/// walks this build simulates, can tell a dataset drawn by another.
pub fn simulator_fingerprint() -> &'static str {
    static FINGERPRINT: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    FINGERPRINT.get_or_init(|| {
        let sampler = ConditionSampler {
            tau: TauSampler::Uniform {
                min: 0.5,
                max: 12.0,
            },
            g: GSampler::Uniform {
                min: -0.95,
                max: 0.95,
            },
            albedo: AlbedoSampler::Uniform { min: 0.3, max: 1.0 },
        };
        let isotropic = ConditionSampler::fixed(crate::conditions::Conditions {
            tau: 5.0,
            g: 0.0,
            albedo: 1.0,
        });
        let clamped = ConditionSampler {
            tau: TauSampler::Fixed { value: 3.0 },
            g: GSampler::Uniform { min: 1.0, max: 1.0 },
            albedo: AlbedoSampler::Fixed { value: 0.9 },
        };
        let runs = [
            (&sampler, 64),
            (&ConditionSampler::authors(), 16),
            (&isotropic, 8),
            (&clamped, 8),
        ];
        let mut crc = crc32fast::Hasher::new();
        let mut bytes = [0u8; super::ROW_BYTES];
        for (sampler, walks) in runs {
            for i in 0..walks {
                walk_row(0x5107_1A70, sampler, i).0.encode(&mut bytes);
                crc.update(&bytes);
            }
        }
        format!("{:08x}", crc.finalize())
    })
}

/// Totals of a generation run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GenerateSummary {
    pub walks: u64,
    pub events: u64,
    pub max_events: u64,
}

/// Walk `index` of the run with `seed` and `sampler`: its row and its event count.
pub fn walk_row(seed: u64, sampler: &ConditionSampler, index: u64) -> (Row, u64) {
    let mut rng = WalkRng::for_walk(seed, index);
    let c = sampler.sample(&mut rng);
    let walk = simulate_walk(c.tau, c.g, c.albedo, &mut rng);
    (Row::new(c, &walk.canonical()), walk.n)
}

/// Generates the spec's rows into `sink` on the current rayon pool. `progress` is called
/// after each chunk with the walks and events done so far; setting `cancel` stops once the
/// walks under way end and returns an error (the sink is dropped, so no output file
/// appears).
pub fn generate(
    spec: &GenerateSpec,
    sink: &mut dyn RowSink,
    cancel: &AtomicBool,
    progress: &mut dyn FnMut(&GenerateSummary),
) -> Result<GenerateSummary, DatasetError> {
    let mut summary = GenerateSummary::default();
    let range = spec.range();
    let mut start = range.start;
    let mut chunk: Vec<Option<(Row, u64)>> = Vec::with_capacity(CHUNK as usize);
    while start < range.end {
        if cancel.load(Ordering::Relaxed) {
            return Err(DatasetError::Interrupted);
        }
        // Not start + CHUNK: a shard ending at walk u64::MAX would wrap it and never end.
        let end = start + (range.end - start).min(CHUNK);
        // Each walk looks at `cancel` too: at τ = 1000 a chunk is minutes of work (walks
        // of ~10⁶ events), and a scheduler's SIGKILL after its grace period found the
        // temporary file still there.
        (0..(end - start) as usize)
            .into_par_iter()
            .map(|j| {
                (!cancel.load(Ordering::Relaxed))
                    .then(|| walk_row(spec.seed, &spec.sampler, start + j as u64))
            })
            .collect_into_vec(&mut chunk);
        if cancel.load(Ordering::Relaxed) {
            return Err(DatasetError::Interrupted);
        }
        for (row, n) in chunk.iter().flatten() {
            sink.push(row)?;
            summary.events += n;
            summary.max_events = summary.max_events.max(*n);
        }
        summary.walks += end - start;
        progress(&summary);
        start = end;
    }
    Ok(summary)
}

/// `n` walks that no row of a dataset with these `pieces` holds, from the same
/// distribution: walks `total_walks, total_walks + 1, …` of each run the pieces come
/// from, which that run would have drawn next (walk i depends on (seed, sampler, i) alone,
/// so they are also the rows a larger run of the same seed would hold there). Runs of one
/// seed and sampler are one stream whatever their sizes: its held-out walks start after
/// the largest run's end (the smaller run's next walks are the larger one's rows). The
/// `n` walks are shared among the streams by their row counts (largest remainder), and
/// returned stream by stream. Held-out walks for a validation loss cost a simulation of
/// `n` walks, not rows taken from training. A stream has none past walk index 2^64 − 1
/// (a run of u64::MAX walks has one): fewer than `n` are returned then, rather than
/// indices that wrap round to the run's own first rows.
pub fn held_out_rows(pieces: &[Piece], n: u64) -> Vec<Row> {
    // (a piece of the stream, where its held-out walks start, its rows)
    let mut streams: Vec<(&Piece, u64, u64)> = Vec::new();
    for p in pieces {
        match streams.iter_mut().find(|(r, _, _)| r.same_stream(p)) {
            Some((_, start, count)) => {
                *start = (*start).max(p.total_walks);
                *count += p.count;
            }
            None => streams.push((p, p.total_walks, p.count)),
        }
    }
    let total: u128 = streams.iter().map(|s| s.2 as u128).sum();
    if total == 0 || n == 0 {
        return Vec::new();
    }
    let mut share: Vec<(u64, u128)> = streams
        .iter()
        .map(|s| {
            let exact = n as u128 * s.2 as u128;
            ((exact / total) as u64, exact % total)
        })
        .collect();
    let given: u64 = share.iter().map(|s| s.0).sum();
    let mut order: Vec<usize> = (0..share.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(share[i].1));
    for &i in order.iter().take((n - given) as usize) {
        share[i].0 += 1;
    }
    let jobs: Vec<(&Piece, u64)> = streams
        .iter()
        .zip(&share)
        .flat_map(|(&(run, start, _), (k, _))| {
            (0..*k).map_while(move |j| start.checked_add(j).map(|i| (run, i)))
        })
        .collect();
    jobs.into_par_iter()
        .map(|(run, index)| walk_row(run.seed, &run.sampler, index).0)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conditions::Conditions;

    /// Walks `first .. first + count` of the run with `seed` of `total` walks, at τ = 2,
    /// g = 0.3, φ = 0.9 (a few events a walk).
    fn piece(seed: u64, total: u64, first: u64, count: u64) -> Piece {
        Piece {
            seed,
            sampler: ConditionSampler::fixed(Conditions {
                tau: 2.0,
                g: 0.3,
                albedo: 0.9,
            }),
            total_walks: total,
            first_walk: first,
            count,
            simulator: None,
        }
    }

    /// The rows of walks `indices` of `p`'s stream.
    fn walks(p: &Piece, indices: Range<u64>) -> Vec<Row> {
        indices.map(|i| walk_row(p.seed, &p.sampler, i).0).collect()
    }

    /// A run of u64::MAX walks (`generate --samples 18446744073709551615 --shard …` writes
    /// one) has a single walk past its end, index 2^64 − 1: its held-out walks stop there
    /// instead of wrapping round to walks 0, 1, …, the run's own rows, which would have
    /// made the validation loss a training loss.
    #[test]
    fn held_out_walks_never_wrap_into_the_dataset() {
        let p = piece(7, u64::MAX, 0, 5);
        let held = held_out_rows(std::slice::from_ref(&p), 3);
        assert_eq!(held, vec![walk_row(p.seed, &p.sampler, u64::MAX).0]);
    }

    /// Held-out walks are walks no row of the dataset holds. A run of 10 walks merged with
    /// the second half (walks 10..20) of a run of 20 of the same seed and sampler is one
    /// stream holding walks 0..20: its held-out walks are 20, 21, 22, past the larger run's
    /// end, in either order of the pieces. Starting after the smaller run (10, 11, 12) would
    /// take the larger run's training rows as held-out walks, and the validation loss could
    /// no longer tell memorising. (Every CLI training test has a single piece, where the
    /// two starts agree.)
    #[test]
    fn held_out_walks_start_after_the_largest_run_of_their_stream() {
        let (small, large) = (piece(7, 10, 0, 10), piece(7, 20, 10, 10));
        let want = walks(&small, 20..23);
        for pieces in [
            [small.clone(), large.clone()],
            [large.clone(), small.clone()],
        ] {
            assert_eq!(held_out_rows(&pieces, 3), want);
        }
        // One run: the walks it would have drawn next.
        assert_eq!(
            held_out_rows(std::slice::from_ref(&small), 2),
            walks(&small, 10..12)
        );
    }

    /// The held-out walks are shared among the streams by their rows, the walks left over
    /// going to the largest remainders: 2 walks over streams of 1 and 2 rows are shares of
    /// 2/3 and 4/3, so each stream gets one (1 + remainder 1/3 for the larger, 0 +
    /// remainder 2/3 for the smaller). The left-over walk given to the smallest remainder
    /// instead leaves the 1-row stream none and gives the other both.
    #[test]
    fn held_out_walks_are_shared_by_largest_remainder() {
        let (one, two) = (piece(3, 5, 0, 1), piece(4, 8, 0, 2));
        let mut want = walks(&one, 5..6);
        want.extend(walks(&two, 8..9));
        assert_eq!(held_out_rows(&[one, two], 2), want);
    }
}
