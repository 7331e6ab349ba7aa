//! Many paths traced together, so that the decoders and the exact steps' walks run in
//! batches.
//!
//! One path's sphere step evaluates three small decoders in a row (LengthGen, PathGen,
//! EventGen), each a chain of short dependent dot products that leaves the CPU's vector
//! units mostly idle; an exact step's walk is a serial chain too. Here a thread keeps
//! [`SLOTS`] paths in flight: each is followed until its next sphere step needs the
//! decoders or a simulated walk (or until it ends, when the next camera sample takes its
//! slot). Then the waiting walks are simulated together in SIMD lanes
//! (`walk_lanes::simulate`), every waiting model step's LengthGen draw is evaluated in
//! one batch with the draws in SIMD lanes ([`cvae::decoder::Decoder::outputs`]), then
//! their PathGen draws, then their EventGen draws, and the steps are finished. Each path
//! keeps its own random stream and draws from it in the same order as when traced alone
//! (a walk from its own stream, seeded from the path's), so the result does not depend on
//! which paths share a batch (only f32 rounding of the decoders' sums does).

use cvae::decoder::{Decoder, Draw, MAX_OUT, Output};
use glam::{DVec3, Vec3};
use scatter_sim::rng::WalkRng;

use super::sphere_step::{Pending, Waiting, exact_shared};
use super::walk_lanes::{self, WalkJob, WalkOutcome};
use super::{Advance, IntegratorSettings, Path, PathStats};
use crate::geometry::Hit;
use crate::setup::SceneData;
use cvae::sampler::CENTRE_EVENT;

/// Paths in flight per thread: enough for full SIMD batches of decoder draws and exact
/// walks while paths end and start at different times, few enough that their state
/// (680 B a path, 170 KB) stays in the core's L2 cache. Measured on the bunny ladder
/// with exact steps in the wavefront: 128 slots +3–5 % over 64 at k = 4 and 8, 256
/// another ~2 %; k = 1 and the default scene within noise.
pub const SLOTS: usize = 256;

/// One camera sample: its ray, hero channel, random stream and a tag the caller uses to
/// place the result.
pub struct Sample {
    pub origin: Vec3,
    pub dir: Vec3,
    /// The camera ray's first hit when the caller has cast it already (samples that share
    /// a ray); None: the path casts it.
    pub first_hit: Option<Option<Hit>>,
    pub channel: usize,
    pub rng: WalkRng,
    pub tag: u64,
}

/// A path in flight.
struct Slot {
    path: Path,
    tag: u64,
}

/// Reused buffers of one batch round.
#[derive(Default)]
struct Batch {
    draws: Vec<Draw>,
    outputs: Vec<Output>,
    /// Every waiting step's representative events in order (None: the centre event).
    events: Vec<Option<Draw>>,
    /// Where each waiting step's events start in `events`.
    event_start: Vec<usize>,
    event_results: Vec<(DVec3, DVec3)>,
    /// The waiting slots whose step is exact, and those whose step needs the decoders.
    exact: Vec<usize>,
    model: Vec<usize>,
    walks: Vec<WalkJob>,
    outcomes: Vec<WalkOutcome>,
}

/// Traces every sample `next` yields and reports each result to `done(tag, channel,
/// radiance, stats)`. Results come in an order fixed by the samples alone, not by threads.
/// False when `stop` ended it with paths unfinished (their results are not reported; the
/// caller drops the batch).
pub fn trace_many(
    scene: &SceneData,
    set: &IntegratorSettings,
    mut next: impl FnMut() -> Option<Sample>,
    mut done: impl FnMut(u64, usize, f32, &PathStats),
    stop: &std::sync::atomic::AtomicBool,
) -> bool {
    let mut slots: Vec<Option<Slot>> = (0..SLOTS).map(|_| None).collect();
    let mut batch = Batch::default();
    let mut waiting: Vec<usize> = Vec::with_capacity(SLOTS);
    loop {
        waiting.clear();
        for (i, cell) in slots.iter_mut().enumerate() {
            loop {
                if cell.is_none() {
                    // Also checked here: an ordinary path never reaches the in-path check
                    // (every STOP_CHECK_EVERY iterations), so Ctrl-C waited for a whole
                    // tile of PT in a dense medium (4–6 s).
                    if stop.load(std::sync::atomic::Ordering::Relaxed) {
                        return false;
                    }
                    let Some(s) = next() else { break };
                    let mut path = Path::new(s.origin, s.dir, s.channel, s.rng);
                    path.first_hit = s.first_hit;
                    *cell = Some(Slot { path, tag: s.tag });
                }
                let slot = cell.as_mut().expect("filled above");
                match slot.path.advance(scene, set, stop) {
                    Advance::Done(l) => {
                        done(slot.tag, slot.path.channel, l, &slot.path.stats);
                        *cell = None;
                    }
                    Advance::Stopped => return false,
                    Advance::Step => {
                        waiting.push(i);
                        break;
                    }
                }
            }
        }
        if waiting.is_empty() {
            return true;
        }
        resolve_steps(scene, set, &mut slots, &waiting, &mut batch);
    }
}

/// Traces one path to its end, its decoder draws one at a time.
pub(crate) fn trace_alone(scene: &SceneData, set: &IntegratorSettings, path: Path) -> (f32, Path) {
    let mut slots = [Some(Slot { path, tag: 0 })];
    let mut batch = Batch::default();
    loop {
        let slot = slots[0].as_mut().expect("one slot");
        match slot.path.advance(scene, set, &super::NEVER) {
            Advance::Done(l) => {
                let slot = slots[0].take().expect("one slot");
                return (l, slot.path);
            }
            Advance::Step => {}
            Advance::Stopped => unreachable!("NEVER is never set"),
        }
        resolve_steps(scene, set, &mut slots, &[0], &mut batch);
    }
}

/// Finishes the sphere steps the slots `waiting` hold: the exact ones' walks simulated
/// together, and the decoder stages of the others run in batches.
fn resolve_steps(
    scene: &SceneData,
    set: &IntegratorSettings,
    slots: &mut [Option<Slot>],
    waiting: &[usize],
    b: &mut Batch,
) {
    let (mut exact, mut model) = (std::mem::take(&mut b.exact), std::mem::take(&mut b.model));
    exact.clear();
    model.clear();
    for &i in waiting {
        let path = &slots[i].as_ref().expect("a waiting slot").path;
        if let Some(Waiting::Exact(_)) = path.step {
            exact.push(i);
        } else {
            model.push(i);
        }
    }
    if !exact.is_empty() {
        resolve_exact(scene, set, slots, &exact, b);
    }
    if !model.is_empty() {
        resolve_model(scene, set, slots, &model, b);
    }
    (b.exact, b.model) = (exact, model);
}

/// Simulates the walks of the exact steps the slots `waiting` hold and finishes the steps.
fn resolve_exact(
    scene: &SceneData,
    set: &IntegratorSettings,
    slots: &mut [Option<Slot>],
    waiting: &[usize],
    b: &mut Batch,
) {
    b.walks.clear();
    b.walks.extend(waiting.iter().map(|&i| {
        let path = &slots[i].as_ref().expect("a waiting slot").path;
        match &path.step {
            Some(Waiting::Exact(step)) => step.job,
            _ => unreachable!("an exact step waits in slot {i}"),
        }
    }));
    b.outcomes.resize(b.walks.len(), WalkOutcome::default());
    walk_lanes::simulate(&b.walks, &exact_shared(scene, set), &mut b.outcomes);
    for (&i, walk) in waiting.iter().zip(&b.outcomes) {
        let path = &mut slots[i].as_mut().expect("a waiting slot").path;
        let Some(Waiting::Exact(step)) = path.step.take() else {
            unreachable!("an exact step waits in slot {i}")
        };
        path.stats.exact_events += walk.n as u64;
        step.finish(scene, set, path.channel, &mut path.s, walk, &mut path.rng);
    }
}

/// Runs the decoder stages of the steps the slots `waiting` hold (all at LengthGen) and
/// finishes the steps.
fn resolve_model(
    scene: &SceneData,
    set: &IntegratorSettings,
    slots: &mut [Option<Slot>],
    waiting: &[usize],
    b: &mut Batch,
) {
    let model = set.model.expect("a waiting sphere step has a model");
    // LengthGen, then PathGen: one batch each over all waiting steps.
    stage_outputs(&model.length, slots, waiting, b);
    for (&i, out) in waiting.iter().zip(&b.outputs) {
        let (rng, step) = pending(slots, i);
        step.after_length(model, out, rng);
    }
    stage_outputs(&model.path, slots, waiting, b);
    b.events.clear();
    b.event_start.clear();
    for (&i, out) in waiting.iter().zip(&b.outputs) {
        let (rng, step) = pending(slots, i);
        b.event_start.push(b.events.len());
        step.after_path(model, set, out, rng, &mut b.events);
    }
    b.event_start.push(b.events.len());
    // EventGen: every drawn event of every step in one batch.
    b.draws.clear();
    b.draws.extend(b.events.iter().flatten().copied());
    b.outputs.resize(b.draws.len(), [0.0; MAX_OUT]);
    model.event.outputs(&b.draws, &mut b.outputs);
    b.event_results.clear();
    let mut outputs = b.outputs.iter();
    for e in &b.events {
        b.event_results.push(match e {
            None => CENTRE_EVENT,
            Some(_) => model.event_result(outputs.next().expect("one output per drawn event")),
        });
    }
    for (k, &i) in waiting.iter().enumerate() {
        let path = &mut slots[i].as_mut().expect("a waiting slot").path;
        let events = &b.event_results[b.event_start[k]..b.event_start[k + 1]];
        let Some(Waiting::Model(step)) = path.step.take() else {
            unreachable!("a model step waits in slot {i}")
        };
        step.finish(scene, set, path.channel, &mut path.s, events, &mut path.rng);
    }
}

/// The outputs of the waiting steps' current draws, into `b.outputs`.
fn stage_outputs(decoder: &Decoder, slots: &mut [Option<Slot>], waiting: &[usize], b: &mut Batch) {
    b.draws.clear();
    b.draws
        .extend(waiting.iter().map(|&i| pending(slots, i).1.draw));
    b.outputs.resize(b.draws.len(), [0.0; MAX_OUT]);
    decoder.outputs(&b.draws, &mut b.outputs);
}

/// The random stream and the waiting step of slot `i`.
fn pending(slots: &mut [Option<Slot>], i: usize) -> (&mut WalkRng, &mut Pending) {
    let path = &mut slots[i].as_mut().expect("a waiting slot").path;
    match &mut path.step {
        Some(Waiting::Model(step)) => (&mut path.rng, step),
        _ => unreachable!("a model step waits in slot {i}"),
    }
}
