//! The model file round-trips and rejects damaged files with clear errors; the sampler
//! never returns invalid walks whatever the weights.

use std::path::Path;

use cvae::decoder::{Decoder, Dense};
use cvae::model_file::{ModelError, ModelSet, SingleScattering, TrainingInfo};
use scatter_sim::WalkRng;

fn random_decoder(
    rng: &mut WalkRng,
    cond: usize,
    latent: usize,
    hidden: &[usize],
    out: usize,
    gain: f32,
) -> Decoder {
    let widths: Vec<usize> = std::iter::once(cond + latent)
        .chain(hidden.iter().copied())
        .chain([2 * out])
        .collect();
    let layers = widths
        .windows(2)
        .map(|w| {
            Dense::new(
                w[0],
                w[1],
                (0..w[0] * w[1])
                    .map(|_| gain * (rng.uniform() as f32 - 0.5))
                    .collect(),
                (0..w[1])
                    .map(|_| gain * (rng.uniform() as f32 - 0.5))
                    .collect(),
            )
        })
        .collect();
    Decoder {
        cond,
        latent,
        out,
        layers,
        cond_shift: vec![0.1; cond],
        cond_scale: vec![1.5; cond],
        out_shift: vec![0.0; out],
        out_scale: vec![1.0; out],
    }
}

pub fn random_models(seed: u64, gain: f32) -> ModelSet {
    let mut rng = WalkRng::from_seed(seed);
    ModelSet {
        feature_version: cvae::features::FEATURE_VERSION,
        single_scattering: SingleScattering::Exact,
        training: TrainingInfo {
            tau_range: [0.0, 300.0],
            g_range: [-0.999, 0.999],
            albedo_range: [0.0, 1.0],
            notes: "random test weights".into(),
        },
        length: random_decoder(&mut rng, 2, 2, &[8, 8], 1, gain),
        path: random_decoder(&mut rng, 3, 5, &[16, 16, 16], 3, gain),
        event: random_decoder(&mut rng, 7, 5, &[12, 12, 12], 6, gain),
    }
}

#[test]
fn round_trip_and_size() {
    let m = random_models(1, 1.0);
    let bytes = m.to_bytes();
    assert!(
        bytes.len() <= 16 * 1024,
        "model file is {} bytes",
        bytes.len()
    );
    let back = ModelSet::from_bytes(&bytes, Path::new("m.stcvae")).unwrap();
    assert_eq!(back, m);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.stcvae");
    m.save(&p).unwrap();
    assert_eq!(ModelSet::load(&p).unwrap(), m);
}

#[test]
fn damaged_files_are_rejected() {
    let bytes = random_models(2, 1.0).to_bytes();
    let p = Path::new("damaged.stcvae");
    let load = |b: &[u8]| ModelSet::from_bytes(b, p);
    for cut in [0, 5, 15, 40, bytes.len() / 2, bytes.len() - 1] {
        let e = load(&bytes[..cut]).unwrap_err();
        assert!(
            matches!(
                e,
                ModelError::BadMagic { .. }
                    | ModelError::Truncated { .. }
                    | ModelError::Checksum { .. }
            ),
            "cut at {cut}: {e}"
        );
        assert!(e.to_string().contains("damaged.stcvae"));
    }
    let mut flipped = bytes.clone();
    let at = bytes.len() - 100;
    flipped[at] ^= 1;
    assert!(matches!(
        load(&flipped).unwrap_err(),
        ModelError::Checksum { .. }
    ));
    let mut v9 = bytes.clone();
    v9[8] = 9;
    let e = load(&v9).unwrap_err();
    assert!(matches!(e, ModelError::Version { found: 9, .. }), "{e}");
    assert!(matches!(
        load(b"STCVAEDS....").unwrap_err(),
        ModelError::BadMagic { .. }
    ));
}

/// `load` looks at the magic bytes and the size before reading the rest: a dataset given
/// as `--model` (hundreds of MB) was read whole to be refused for its first 8 bytes. The
/// largest model a config may describe stays well inside the bound.
#[test]
fn load_refuses_foreign_and_oversized_files_before_reading_them() {
    use cvae::decoder::{MAX_HIDDEN_LAYERS, MAX_WIDTH};
    use cvae::features::{EVENT_COND, EVENT_OUT, LENGTH_COND, LENGTH_OUT, PATH_COND, PATH_OUT};
    use cvae::model_file::MAX_FILE_BYTES;
    let dir = tempfile::tempdir().unwrap();
    // Sparse files: their size costs no disk, and reading one whole would take seconds
    // and a GiB of memory.
    let sparse = |name: &str, head: &[u8], len: u64| {
        let p = dir.path().join(name);
        std::fs::write(&p, head).unwrap();
        std::fs::OpenOptions::new()
            .write(true)
            .open(&p)
            .unwrap()
            .set_len(len)
            .unwrap();
        p
    };
    let foreign = sparse("train.bin", b"STCVAEDS", 1 << 30);
    let e = ModelSet::load(&foreign).unwrap_err();
    assert!(matches!(e, ModelError::BadMagic { .. }), "{e}");
    let big = sparse(
        "big.stcvae",
        &random_models(4, 1.0).to_bytes()[..8],
        MAX_FILE_BYTES + 1,
    );
    let e = ModelSet::load(&big).unwrap_err().to_string();
    assert!(
        e.contains("big.stcvae") && e.contains("more than any model file"),
        "{e}"
    );
    // An empty file is named as one (a failed copy), not as damaged magic bytes; a short
    // one keeps the magic bytes' message.
    let empty = sparse("empty.stcvae", b"", 0);
    let e = ModelSet::load(&empty).unwrap_err().to_string();
    assert!(
        e.contains("empty.stcvae") && e.contains("the file is empty"),
        "{e}"
    );
    let short = sparse("short.stcvae", b"STC", 3);
    let e = ModelSet::load(&short).unwrap_err();
    assert!(matches!(e, ModelError::BadMagic { .. }), "{e}");
    // A directory is named as one (it read as "bad magic bytes").
    let e = ModelSet::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("is a directory, not a model file"), "{e}");

    let mut rng = WalkRng::from_seed(5);
    let hidden = vec![MAX_WIDTH; MAX_HIDDEN_LAYERS];
    let mut m = random_models(5, 1.0);
    m.length = random_decoder(&mut rng, LENGTH_COND, 16, &hidden, LENGTH_OUT, 1.0);
    // Eight random layers decode absurd walk lengths, which the load probe refuses: a
    // zero head (median N the diffusion count, spread e^1) keeps the size test about size.
    let head = m.length.layers.last_mut().unwrap();
    *head = Dense::new(
        head.inputs,
        head.outputs,
        vec![0.0; head.inputs * head.outputs],
        vec![0.0; head.outputs],
    );
    m.path = random_decoder(&mut rng, PATH_COND, 16, &hidden, PATH_OUT, 1.0);
    m.event = random_decoder(&mut rng, EVENT_COND, 16, &hidden, EVENT_OUT, 1.0);
    let bytes = m.to_bytes();
    assert!(
        (bytes.len() as u64) < MAX_FILE_BYTES / 8,
        "{} bytes",
        bytes.len()
    );
    let p = dir.path().join("largest.stcvae");
    std::fs::write(&p, &bytes).unwrap();
    assert_eq!(ModelSet::load(&p).unwrap(), m);
}

/// Metadata whose sizes overflow (a hand-edited or foreign file with a valid checksum) or
/// whose decoders are deeper than any kernel should unroll is refused by name, not by an
/// arithmetic overflow or a compile that never ends.
#[test]
fn overflowing_metadata_is_refused() {
    let bytes = random_models(4, 1.0).to_bytes();
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let weights = &bytes[16 + json_len..bytes.len() - 4];
    type Edit = (fn(&mut serde_json::Value), &'static str);
    let edits: [Edit; 4] = [
        (|m| m["decoders"][0]["latent"] = u64::MAX.into(), "inputs"),
        // Deep decoders are unrolled into the GPU kernels: 1,000 layers compiled for 31 s.
        (
            |m| m["decoders"][0]["hidden"] = serde_json::json!(vec![1; 1000]),
            "1000 hidden layers; at most 8",
        ),
        (
            |m| m["decoders"][1]["hidden"] = serde_json::json!([1u64 << 32, 1u64 << 32]),
            "layer widths",
        ),
        (
            |m| m["decoders"][2]["out"] = (u64::MAX / 2 + 1).into(),
            "expected",
        ),
    ];
    for (edit, msg) in edits {
        let mut meta: serde_json::Value =
            serde_json::from_slice(&bytes[16..16 + json_len]).unwrap();
        edit(&mut meta);
        let json = serde_json::to_vec(&meta).unwrap();
        let mut b = bytes[..12].to_vec();
        b.extend((json.len() as u32).to_le_bytes());
        b.extend(&json);
        b.extend(weights);
        b.extend(crc32fast::hash(&b).to_le_bytes());
        let e = ModelSet::from_bytes(&b, Path::new("edited.stcvae")).unwrap_err();
        assert!(
            matches!(e, ModelError::Invalid { .. }) && e.to_string().contains(msg),
            "{e}"
        );
    }
}

/// Files of feature version 2 (EventGen's atanh radial map) and 3 load with their own
/// version, which selects how EventGen's output is read; other versions are refused by
/// name, with the range this build reads.
#[test]
fn feature_versions_are_kept_or_refused() {
    use cvae::features::EventRadial;
    for (v, radial) in [(2, EventRadial::Atanh), (3, EventRadial::GaussianEdge)] {
        let mut m = random_models(6, 1.0);
        m.feature_version = v;
        let back = ModelSet::from_bytes(&m.to_bytes(), Path::new("v.stcvae")).unwrap();
        assert_eq!(back.feature_version, v);
        assert_eq!(back.event_radial(), radial);
    }
    for v in [1, 4] {
        let mut m = random_models(6, 1.0);
        m.feature_version = v;
        let e = ModelSet::from_bytes(&m.to_bytes(), Path::new("v.stcvae")).unwrap_err();
        assert!(
            e.to_string()
                .contains(&format!("feature version {v} (this build reads 2 to 3)")),
            "{e}"
        );
    }
}

/// Non-finite weights are refused even with a valid checksum.
#[test]
fn non_finite_weights_are_refused() {
    let mut m = random_models(3, 1.0);
    m.path.layers[1].weight[3] = f32::NAN;
    let e = ModelSet::from_bytes(&m.to_bytes(), Path::new("nan.stcvae")).unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
    // Finite but absurd: overflows f32 activations.
    let mut m = random_models(3, 1.0);
    m.event.layers[0].bias[0] = 1e30;
    let e = ModelSet::from_bytes(&m.to_bytes(), Path::new("big.stcvae")).unwrap_err();
    assert!(e.to_string().contains("beyond"), "{e}");
}

/// Standardisation far outside what any feature needs (a hand-edited file whose checksum
/// was recomputed) is refused by field and index: an out_scale of 1e38 rendered a
/// too-bright image from walks with N = 2^32 − 1 without a word.
#[test]
fn absurd_standardisation_is_refused() {
    type Edit = (fn(&mut ModelSet), &'static str);
    let cases: [Edit; 5] = [
        (
            |m| m.length.out_scale[0] = 1e38,
            "lengthgen: out_scale[0] = 1e38 is out of range: allowed [1e-6, 100]",
        ),
        (
            |m| m.path.cond_scale[2] = 0.0,
            "pathgen: cond_scale[2] = 0 is out of range",
        ),
        (
            |m| m.event.out_shift[5] = -1e3,
            "eventgen: out_shift[5] = -1000 is out of range: allowed [-100, 100]",
        ),
        // (A NaN cannot be stored: the metadata is JSON, which writes it as null.)
        (
            |m| m.event.cond_shift[1] = 1e30,
            "eventgen: cond_shift[1] = 1e30 is out of range",
        ),
        (
            |m| m.path.out_scale.push(1.0),
            "pathgen: out_scale has 4 values, expected 3",
        ),
    ];
    for (edit, msg) in cases {
        let mut m = random_models(5, 1.0);
        edit(&mut m);
        let e = ModelSet::from_bytes(&m.to_bytes(), Path::new("n.stcvae")).unwrap_err();
        assert!(e.to_string().contains(msg), "{e}");
    }
    // Older builds' scale for a column without spread, 10⁻⁶, is accepted and read as
    // today's 1 (model_file::lift_old_floor: kept, any condition off the training value
    // reached the network a million times larger); other scales are kept.
    let mut m = random_models(5, 1.0);
    m.path.cond_scale[1] = 1e-6f64 as f32;
    m.event.out_scale[0] = 1e-6f64 as f32;
    let back = ModelSet::from_bytes(&m.to_bytes(), Path::new("n.stcvae")).unwrap();
    assert_eq!(back.path.cond_scale[1], 1.0);
    assert_eq!(back.event.out_scale[0], 1.0);
    assert_eq!(back.length.cond_scale, m.length.cond_scale);
    assert_eq!(back.path.cond_scale[0], m.path.cond_scale[0]);
}

/// The training ranges steer the renderers' τ cap and warnings: unordered or
/// out-of-range ones are refused by name even with a valid checksum.
#[test]
fn bad_training_ranges_are_refused() {
    type Edit = (fn(&mut TrainingInfo), &'static str);
    let cases: [Edit; 4] = [
        (|t| t.tau_range = [300.0, 0.0], "tau_range"),
        (|t| t.tau_range = [0.0, 1e39], "tau_range"),
        (|t| t.g_range = [-2.0, 0.5], "g_range"),
        (|t| t.albedo_range = [0.5, 0.2], "albedo_range"),
    ];
    for (edit, field) in cases {
        let mut m = random_models(5, 1.0);
        edit(&mut m.training);
        let e = ModelSet::from_bytes(&m.to_bytes(), Path::new("r.stcvae")).unwrap_err();
        assert!(
            matches!(e, ModelError::Invalid { .. }) && e.to_string().contains(field),
            "{e}"
        );
    }
    // One byte too many reads as a size mismatch, not as "truncated" alone.
    let mut long = random_models(5, 1.0).to_bytes();
    long.push(0);
    let e = ModelSet::from_bytes(&long, Path::new("r.stcvae")).unwrap_err();
    assert!(
        e.to_string()
            .contains("truncated, padded or damaged in its header"),
        "{e}"
    );
}

/// A decoder output that is not finite is reported by `sample_walk_checked` (and the walk
/// is the one `sample_walk` draws from the same numbers, repaired into range); a model
/// whose outputs are finite reports none. Here LengthGen's, PathGen's and then EventGen's
/// last bias is made NaN, so every walk with N ≥ 2 (and its event, where EventGen runs) is
/// affected. A NaN length is clamped to a finite N before PathGen reads it, so only
/// LengthGen's own check reports that one.
#[test]
fn non_finite_decoder_outputs_are_reported() {
    let clean = random_models(4, 1.0);
    let draw = |m: &ModelSet, seed: u64| {
        let mut rng = WalkRng::from_seed(seed);
        let (w, bad) = m.sample_walk_checked(5.0, 0.3, 0.99, true, &mut rng);
        let mut rng = WalkRng::from_seed(seed);
        let plain = m.sample_walk(5.0, 0.3, 0.99, true, &mut rng);
        assert_eq!(
            (w.n, w.exit.cos_theta, w.event_pos),
            (plain.n, plain.exit.cos_theta, plain.event_pos)
        );
        (w, bad)
    };
    assert!((0..2_000).all(|s| !draw(&clean, s).1));
    for which in ["length", "path", "event"] {
        let mut m = random_models(4, 1.0);
        let d = match which {
            "length" => &mut m.length,
            "path" => &mut m.path,
            _ => &mut m.event,
        };
        let last = d.layers.len() - 1;
        d.layers[last].bias[0] = f32::NAN;
        let (mut multiple, mut flagged) = (0, 0);
        // EventGen's expected runs and their variance, Σ p and Σ p(1 − p) with
        // p = 1 − φ/Λ(N) (the N are PathGen-independent: EventGen is drawn last).
        let (mut expected, mut variance) = (0.0, 0.0);
        for s in 0..2_000 {
            let (w, bad) = draw(&m, s);
            multiple += u32::from(!w.single);
            flagged += u32::from(bad);
            if !w.single {
                let p = 1.0 - 0.99 / cvae::sampler::lambda(0.99, w.n);
                expected += p;
                variance += p * (1.0 - p);
            }
            // LengthGen and PathGen run for every walk with N ≥ 2; EventGen for those
            // whose event is not event 1 (chosen with probability φ/Λ(N), and then at the
            // centre, where a repaired event lands too, so the two cannot be told apart
            // here).
            if which != "event" {
                assert_eq!(bad, !w.single, "{which}, seed {s}");
            } else {
                assert!(!bad || !w.single, "{which}, seed {s}");
            }
        }
        assert!(
            multiple > 1_000,
            "{which}: {multiple} of 2,000 walks had N ≥ 2"
        );
        if which == "event" {
            // A sum of independent Bernoulli draws: |z| < 4 fails a correct report with
            // probability 6e-5 (the normal approximation holds at ~10³ terms).
            let z = (f64::from(flagged) - expected) / variance.sqrt();
            assert!(
                z.abs() < 4.0,
                "{flagged} flagged, {expected:.1} expected: z = {z:.2}"
            );
        }
    }
}

/// Wild weights (gain 40) make the decoders return absurd values; the sampler must
/// still produce valid walks: N ≥ 1, cos θ ∈ [−1, 1], α² + β² ≤ 1, |X| ≤ 1, |W| = 1.
#[test]
fn sampler_output_is_always_valid() {
    for gain in [1.0, 40.0] {
        let m = random_models(4, gain);
        let mut rng = WalkRng::from_seed(8);
        for i in 0..20_000 {
            let tau = 300.0 * rng.uniform().powi(3);
            let g = 1.998 * rng.uniform() - 0.999;
            let w = m.sample_walk(tau, g, 0.99, i % 2 == 0, &mut rng);
            assert!(w.n >= 1);
            assert!(w.exit.cos_theta.abs() <= 1.0);
            assert!(w.exit.alpha.powi(2) + w.exit.beta.powi(2) <= 1.0 + 1e-12);
            assert!(w.event_pos.length() <= 1.0 + 1e-12);
            assert!((w.event_dir.length() - 1.0).abs() < 1e-9);
            if !w.single {
                assert!(w.n >= 2, "N = 1 only comes from the exact branch");
            }
        }
    }
}

/// The exact branch: P(N = 1) = e^{−τ}; with 100,000 draws the fraction's standard
/// error is ≤ 0.0016, and |z| < 4 fails a correct sampler with probability 6e-5. Its
/// exit leaves the centre in an HG direction: the cos θ of its walks follow the HG
/// distribution of the walk's g (one-sample KS, p > 1e-4 for a correct sampler; over the
/// ~74,000 N = 1 walks at τ = 0.3 that is D < ~0.0082; drawn with g = −0.2 or 0.1 in
/// place of 0.2, they gave D = 0.29 and 0.077).
#[test]
fn single_scattering_branch_probability() {
    let m = random_models(5, 1.0);
    let g = 0.2;
    for (i, tau) in [0.3, 1.0, 3.0].into_iter().enumerate() {
        let mut rng = WalkRng::from_seed(50 + i as u64);
        let n = 100_000u64;
        let mut cos: Vec<f64> = (0..n)
            .map(|_| m.sample_walk(tau, g, 1.0, false, &mut rng))
            .filter(|w| w.n == 1)
            .map(|w| w.exit.cos_theta)
            .collect();
        let hits = cos.len() as u64;
        let z = scatter_sim::stats::proportion_z(hits, n, (-tau).exp());
        assert!(z.abs() < 4.0, "tau = {tau}: z = {z:.2}");
        let d =
            scatter_sim::stats::ks_one_sample(&mut cos, |c| scatter_sim::phase::hg_cos_cdf(g, c));
        let p = scatter_sim::stats::ks_p_value(d, hits as f64);
        assert!(
            p > 1e-4,
            "tau = {tau}: KS D = {d:.4} (p = {p:.1e}) against HG"
        );
    }
}

/// The exact centre event: given N and φ, event 1 (X = 0, W = +z) is chosen with
/// probability φ/Λ(N). 100,000 draws per case, |z| < 4 as above. EventGen never returns
/// exactly the centre (its outputs are continuous), so X = 0 identifies the branch.
/// At φ = 0 the probability is its limit φ/Λ(N) → 1 as φ → 0⁺, the simulator's choice
/// (its reservoir keeps event 1): 0/0 read as "never" sent every draw to EventGen.
#[test]
fn centre_event_probability() {
    use scatter_sim::frame::CanonicalExit;
    let m = random_models(6, 1.0);
    let exit = CanonicalExit {
        cos_theta: 0.3,
        alpha: 0.1,
        beta: -0.2,
    };
    for (i, (albedo, n_events)) in [(1.0, 2u64), (0.8, 3), (0.99, 40), (0.0, 5)]
        .into_iter()
        .enumerate()
    {
        let mut rng = WalkRng::from_seed(70 + i as u64);
        let n = 100_000u64;
        let hits = (0..n)
            .filter(|_| {
                m.sample_event(5.0, 0.3, albedo, n_events, exit, &mut rng).0 == glam::DVec3::ZERO
            })
            .count() as u64;
        // Λ(N) = Σ_{k=1..N} φ^k summed here, not by the sampler's own `lambda`.
        let lambda: f64 = (1..=n_events).map(|k| albedo_pow(albedo, k)).sum();
        if albedo == 0.0 {
            assert_eq!(hits, n, "φ = 0 always picks the centre");
            continue;
        }
        let p = albedo / lambda;
        let z = scatter_sim::stats::proportion_z(hits, n, p);
        assert!(
            z.abs() < 4.0,
            "φ = {albedo}, N = {n_events}: p = {p:.4}, z = {z:.2}"
        );
    }
}

/// Λ(N) = Σ φ^k against direct summation, including φ within 1e-5 of 1.
#[test]
fn lambda_matches_direct_sum() {
    for albedo in [0.0, 0.3, 0.9, 0.99999, 1.0] {
        for n in [1u64, 2, 7, 1000] {
            let direct: f64 = (1..=n).map(|k| albedo_pow(albedo, k)).sum();
            let l = cvae::sampler::lambda(albedo, n);
            assert!(
                (l - direct).abs() <= 1e-9 * direct.max(1.0),
                "φ = {albedo}, N = {n}: {l} vs {direct}"
            );
        }
    }
}

fn albedo_pow(a: f64, k: u64) -> f64 {
    a.powi(k as i32)
}

/// Batched evaluation (draws in SIMD lanes) equals one-by-one evaluation. The two sum
/// the same products in another order (and the batch may fuse multiply-adds where the
/// single path does too, or not), so they differ by f32 rounding: a few ulps per layer of
/// values of order 1–10, i.e. well under 1e-4 absolute for these O(1)-gain weights; a
/// wrong lane, a wrong weight index or a missing activation differs by O(0.1–1). Batches
/// of 1, 7, 8, 9 and 37 draws cover a partial group, a full one and several.
#[test]
fn batched_outputs_equal_single_draws() {
    let m = random_models(11, 1.5);
    let mut rng = WalkRng::from_seed(12);
    for decoder in [&m.length, &m.path, &m.event] {
        for n in [1usize, 7, 8, 9, 37] {
            let draws: Vec<_> = (0..n)
                .map(|_| {
                    let cond: Vec<f64> = (0..decoder.cond)
                        .map(|_| 4.0 * rng.uniform() - 2.0)
                        .collect();
                    let z: Vec<f32> = (0..decoder.latent).map(|_| rng.standard_normal()).collect();
                    let eps: Vec<f32> = (0..decoder.out).map(|_| rng.standard_normal()).collect();
                    decoder.draw(&cond, &z, &eps)
                })
                .collect();
            // The batched outputs (mean + exp(½ logvar)·eps, de-standardised) equal the
            // one-draw definition on the single heads.
            let mut outs = vec![[0f32; cvae::decoder::MAX_OUT]; n];
            decoder.outputs(&draws, &mut outs);
            for (d, o) in draws.iter().zip(&outs) {
                let single = decoder.read_out(&decoder.head(d), d);
                for j in 0..decoder.out {
                    let e = (single[j] - o[j]).abs() / single[j].abs().max(1.0);
                    assert!(
                        e < 1e-4,
                        "batch of {n}: output {j} {} vs {}",
                        o[j],
                        single[j]
                    );
                }
            }
        }
    }
}

/// `event_draws` pairs its draws antithetically; each must still have the distribution of
/// an independent `event_draw`, centre events included, or the NEE average it feeds would
/// be biased. 20,000 second-of-pair events against 20,000 independent ones: two-sample KS
/// on the event radius |X| and on W_z, where D > 1.95·√(2/20,000) = 0.0195 has probability
/// 0.1 % under the null (the centre's point mass at |X| = 0 is part of both samples), and
/// the centre's share against its probability φ/Λ(N) (|z| < 4). The pairs must really be
/// mirrored: a second draw's latent and output normals are the first's negated. The
/// shipped model, not random weights: with those, a mirror that scaled the latent by 1.5
/// went unseen (KS 0.01); with the shipped model it fails (KS 0.058).
#[test]
fn antithetic_event_draws_keep_the_marginal() {
    use cvae::ModelWalk;
    use cvae::features::WalkFeatures;
    use scatter_sim::frame::CanonicalExit;
    // The shipped model: its events depend on the latent noise as a trained model's do.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.stcvae");
    let m = ModelSet::load(&path).unwrap();
    let exit = CanonicalExit {
        cos_theta: 0.3,
        alpha: 0.1,
        beta: -0.2,
    };
    let albedo = 0.9;
    let features = WalkFeatures::new(5.0, 0.3, albedo);
    let walk = ModelWalk::multiple(6, exit, features, albedo);
    let mut rng = WalkRng::from_seed(22);
    let n = 20_000;
    let event = |d: &Option<cvae::decoder::Draw>| match d {
        None => cvae::sampler::CENTRE_EVENT,
        Some(d) => m.event_result(&m.event.output(d)),
    };
    let (mut second_r, mut second_w, mut alone_r, mut alone_w) = (vec![], vec![], vec![], vec![]);
    let mut centres = 0u64;
    let mut draws = Vec::new();
    for _ in 0..n {
        draws.clear();
        m.event_draws(&walk, 2, &mut rng, &mut draws);
        if let [Some(a), Some(b)] = draws[..] {
            // Checked element by element, not through `Decoder::mirrored` (which built
            // `b`): the conditions are shared, the latent and output normals negated.
            let (cond, latent, out) = (m.event.cond, m.event.latent, m.event.out);
            for (i, (&x, &y)) in a.input.iter().zip(&b.input).enumerate() {
                let want = if (cond..cond + latent).contains(&i) {
                    -x
                } else {
                    x
                };
                assert_eq!(y, want, "input {i} of the second draw");
            }
            for (j, (&x, &y)) in a.eps.iter().zip(&b.eps).enumerate() {
                let want = if j < out { -x } else { x };
                assert_eq!(y, want, "output normal {j} of the second draw");
            }
            assert!(latent > 0 && a.input[cond..cond + latent].iter().any(|&v| v != 0.0));
        }
        let (x, w) = event(&draws[1]);
        centres += u64::from(draws[1].is_none());
        second_r.push(x.length());
        second_w.push(w.z);
        let (x, w) = event(&m.event_draw(&walk, &mut rng));
        alone_r.push(x.length());
        alone_w.push(w.z);
    }
    let ks_r = scatter_sim::stats::ks_two_sample(&mut second_r, &mut alone_r);
    let ks_w = scatter_sim::stats::ks_two_sample(&mut second_w, &mut alone_w);
    assert!(
        ks_r < 0.0195 && ks_w < 0.0195,
        "KS |X| {ks_r:.4}, W_z {ks_w:.4}"
    );
    // Λ(6) = Σ_{k=1..6} φ^k summed here, not taken from the sampler's own `walk.lambda`.
    let lambda: f64 = (1..=6).map(|k| albedo_pow(albedo, k)).sum();
    let p = albedo / lambda;
    let z = scatter_sim::stats::proportion_z(centres, n as u64, p);
    assert!(z.abs() < 4.0, "centre share: p = {p:.4}, z = {z:.2}");
}

/// LengthGen is probed on load: weights and standardisation each inside their bounds
/// decoded N = e^100 (rendered at 1e13 without a word). A median beyond e^±8 times the
/// diffusion count, or a spread above e^4, is refused by condition and latent draw; the
/// random test weights (O(1) outputs, like a trained file's) pass.
#[test]
fn absurd_lengthgen_is_refused() {
    let load = |m: &ModelSet| ModelSet::from_bytes(&m.to_bytes(), Path::new("n.stcvae"));
    let mut m = random_models(5, 1.0);
    load(&m).unwrap();
    m.length.out_shift[0] = 50.0;
    let e = load(&m).unwrap_err().to_string();
    assert!(
        e.contains("n.stcvae: invalid model: lengthgen: at τ = 0, g = -0.999 it decodes ln N = ln(diffusion count) + 48.9 ± 0.7"),
        "{e}"
    );
    assert!(e.contains("damaged or hand-edited"), "{e}");
    // The log-variance head's bias at the weight bound: a spread of e^(8 × out_scale).
    let mut m = random_models(5, 1.0);
    let head = m.length.layers.last_mut().unwrap();
    let mut bias = head.bias.clone();
    bias[1] = 1e4;
    *head = Dense::new(head.inputs, head.outputs, head.weight.clone(), bias);
    let e = load(&m).unwrap_err().to_string();
    assert!(e.contains("+ -1.1 ± 2981.0 (median ± spread)"), "{e}");
    // Latent weights at the bound leave the latent mean's decoding alone: such a file
    // (the shipped model so edited, checksum recomputed) decoded a mean N of 2·10⁹ away
    // from z = 0. The probes 3 standard deviations out along each latent axis refuse it.
    let mut m = random_models(5, 1.0);
    let (cond, latent) = (m.length.cond, m.length.latent);
    let first = &mut m.length.layers[0];
    let mut weight = first.weight.clone();
    for o in 0..first.outputs {
        for i in cond..cond + latent {
            weight[o * first.inputs + i] = 1e4;
        }
    }
    *first = Dense::new(first.inputs, first.outputs, weight, first.bias.clone());
    let e = load(&m).unwrap_err().to_string();
    assert!(e.contains("-0.999 and latent [3.0"), "{e}");
    assert!(e.contains("damaged or hand-edited"), "{e}");
}

/// PathGen and EventGen are probed on load too: the samplers replace a non-finite output
/// by a fixed valid one, so weights each within the bound that overflow to inf (8 layers
/// of 64, every weight 10⁴: activations grow ~6·10⁵-fold a layer) loaded and rendered
/// every exit at α = β = 0 without a word. Refused, naming the model; the random test
/// weights pass.
#[test]
fn non_finite_decoders_are_refused() {
    let load = |m: &ModelSet| ModelSet::from_bytes(&m.to_bytes(), Path::new("n.stcvae"));
    for which in ["pathgen", "eventgen"] {
        let mut m = random_models(5, 1.0);
        load(&m).unwrap();
        let d = if which == "pathgen" {
            &mut m.path
        } else {
            &mut m.event
        };
        let mut rng = WalkRng::from_seed(9);
        let mut wide = random_decoder(&mut rng, d.cond, d.latent, &[64; 8], d.out, 1.0);
        wide.layers = wide
            .layers
            .iter()
            .map(|l| {
                Dense::new(
                    l.inputs,
                    l.outputs,
                    vec![1e4; l.weight.len()],
                    l.bias.clone(),
                )
            })
            .collect();
        *d = wide;
        let e = load(&m).unwrap_err().to_string();
        assert!(
            e.contains(&format!(
                "n.stcvae: invalid model: {which}: its output is not finite"
            )) && e.contains("damaged or hand-edited"),
            "{e}"
        );
    }
}

/// EventGen's conditions in a render are the ones it was trained on: the training table
/// builds them from a walk's row as `features::event_cond(τ, g, φ, N, cos θ, β, α)`
/// (train/data.rs, the dataset's column order), and `event_draw` must give the same for
/// a walk whose exit has those values (α ≠ β, so an exit passed as (α, β) shows; the
/// model-file probes use α = β). Exact, f32 of the same f64s.
#[test]
fn event_draws_take_the_conditions_training_gave() {
    use cvae::ModelWalk;
    use cvae::features::WalkFeatures;
    use scatter_sim::frame::CanonicalExit;
    let m = random_models(6, 1.0);
    let exit = CanonicalExit {
        cos_theta: 0.3,
        alpha: 0.1,
        beta: -0.2,
    };
    let (tau, g, albedo, n) = (5.0, 0.3, 0.9, 6);
    let walk = ModelWalk::multiple(n, exit, WalkFeatures::new(tau, g, albedo), albedo);
    let mut rng = WalkRng::from_seed(4);
    // Exact mode picks the centre with probability φ/Λ(6) (no decoder): draw until not.
    let d = (0..100)
        .find_map(|_| m.event_draw(&walk, &mut rng))
        .expect("a decoder draw in 100 tries");
    let trained = cvae::features::event_cond(tau, g, albedo, n, 0.3, -0.2, 0.1);
    // The decoder's standardisation of the trained conditions, (c − shift)/scale.
    let e = &m.event;
    assert_eq!(e.cond, trained.len());
    let want: Vec<f32> = (0..e.cond)
        .map(|i| (trained[i] as f32 - e.cond_shift[i]) / e.cond_scale[i])
        .collect();
    assert_eq!(d.input[..e.cond], want[..]);
}

/// The exact single-scattering walk (N = 1, event 1 at the centre) carries Λ(1) = φ as
/// its NEE weight and φ as its survival, summed here term by term: Λ(N) = N holds at
/// φ = 1 only. At τ = 1e-9 the branch is taken with probability 1 − 1e-9.
#[test]
fn the_single_scattering_walk_weighs_its_one_event_by_the_albedo() {
    use cvae::features::WalkFeatures;
    let m = random_models(6, 1.0);
    let mut rng = WalkRng::from_seed(8);
    for albedo in [0.0, 0.3, 0.8, 0.99, 1.0] {
        let w = m
            .single_walk(
                WalkFeatures::new(1e-9, 0.2, albedo),
                1e-9,
                0.2,
                albedo,
                &mut rng,
            )
            .expect("the N = 1 branch at τ = 1e-9");
        let lambda: f64 = (1..=1).map(|k| albedo_pow(albedo, k)).sum();
        assert_eq!(
            (w.n, w.lambda, w.survival),
            (1, lambda, albedo),
            "φ = {albedo}"
        );
    }
}

/// `event_draws` with more than two draws a walk: pairs of a fresh draw and its mirror,
/// each pair fresh (a third draw that mirrored the mirror would repeat the first, and
/// four EventGen draws would buy what two do). Draws 0 and 2 never equal, 3 mirrors 2.
/// Each draw is the centre (no decoder) with probability φ/Λ(6) = 0.213, so 2,000 walks
/// have draws 0, 2 and 3 all from the decoder 2000 × 0.787³ = 973 ± 22 times: at least
/// 800 asked (8 sd below).
#[test]
fn event_draws_beyond_a_pair_are_fresh() {
    use cvae::ModelWalk;
    use cvae::features::WalkFeatures;
    use scatter_sim::frame::CanonicalExit;
    let m = random_models(6, 1.0);
    let exit = CanonicalExit {
        cos_theta: 0.3,
        alpha: 0.1,
        beta: -0.2,
    };
    let walk = ModelWalk::multiple(6, exit, WalkFeatures::new(5.0, 0.3, 0.9), 0.9);
    let mut rng = WalkRng::from_seed(10);
    let (mut draws, mut pairs) = (Vec::new(), 0);
    for _ in 0..2000 {
        draws.clear();
        m.event_draws(&walk, 4, &mut rng, &mut draws);
        if let [Some(a), _, Some(c), Some(d)] = &draws[..] {
            pairs += 1;
            assert_ne!(a.input, c.input, "draw 2 repeats draw 0");
            assert_eq!(m.event.mirrored(c).input, d.input, "draw 3 mirrors draw 2");
        }
    }
    assert!(
        pairs >= 800,
        "only {pairs} walks with draws 0, 2 and 3 from the decoder"
    );
}

/// A hidden layer of width 0 (a damaged or hand-edited file, its size and checksum
/// consistent with the metadata) is refused by name like one too wide; read, its layers
/// have no outputs, and evaluating the decoder (the load probes, every render) indexes
/// past them and panics. LengthGen with hidden [0, 8]: 4 inputs → 0 → 8 → 2, its weights
/// and biases the lengths that shape needs (the second layer has only its bias).
#[test]
fn a_hidden_layer_of_width_zero_is_refused() {
    let mut m = random_models(5, 1.0);
    let inputs = m.length.cond + m.length.latent;
    m.length.layers = vec![
        Dense::new(inputs, 0, Vec::new(), Vec::new()),
        Dense::new(0, 8, Vec::new(), vec![0.1; 8]),
        Dense::new(8, 2, vec![0.1; 16], vec![0.0; 2]),
    ];
    let e = ModelSet::from_bytes(&m.to_bytes(), Path::new("w.stcvae"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(
            "w.stcvae: invalid model: lengthgen: layer widths [4, 0, 8, 2] out of range: \
             allowed [1, 64] each"
        ),
        "{e}"
    );
}

/// LengthGen's load probes go out along each latent axis both ways: a LengthGen sane at
/// the latent mean and at z = +3 but absurd at z = −3 is refused, naming the latent point.
/// The network is set by hand (random_models' LengthGen: 2 conditions + 2 latent inputs,
/// hidden [8, 8], one output): every first-layer unit reads the latent inputs with weight
/// −1000 (within the ±1e4 bound) and nothing else, the second layer and the mean head
/// average their inputs (weights 1/8), the log-variance head is 0. Softplus between the
/// layers: at z = 0 the median relative ln N is softplus(softplus(0)) = ln 3 ≈ 1.1 and the
/// spread e^0 = 1 (within ±8 and 4); at z = +3 the first layer is softplus(−3000) ≈ 0,
/// the median ln 2 ≈ 0.7; at z = −3 it is softplus(3000) = 3000 and so is the median,
/// far beyond ±8. The existing test sets the latent weights to +1e4, which the probe at
/// z = +3 already refuses.
#[test]
fn lengthgen_absurd_only_below_the_latent_mean_is_refused() {
    let mut m = random_models(5, 1.0);
    let (cond, latent) = (m.length.cond, m.length.latent);
    let inputs = cond + latent;
    let mut first = vec![0.0f32; 8 * inputs];
    for o in 0..8 {
        for i in cond..inputs {
            first[o * inputs + i] = -1000.0;
        }
    }
    let mut head = vec![0.125f32; 8];
    head.extend([0.0f32; 8]);
    m.length.layers = vec![
        Dense::new(inputs, 8, first, vec![0.0; 8]),
        Dense::new(8, 8, vec![0.125; 64], vec![0.0; 8]),
        Dense::new(8, 2, head, vec![0.0; 2]),
    ];
    let e = ModelSet::from_bytes(&m.to_bytes(), Path::new("n.stcvae"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("n.stcvae: invalid model: lengthgen: ")
            && e.contains("and latent [-3.0, 0.0] it decodes")
            && e.contains("damaged or hand-edited"),
        "{e}"
    );
}

/// A non-finite decoder output is reported whichever of the decoder's outputs holds it,
/// not only the first: PathGen's last bias made NaN at index 2 (the head is [means |
/// log-variances], so that is the mean of output 2, α's target) leaves outputs 0 and 1
/// finite and the exit repaired to α = β = 0, which `sample_walk_checked` must flag for
/// every walk with N ≥ 2 (`sample` warns about them); the walks of the exact N = 1 branch
/// run no decoder and are not flagged. The test above makes the first bias NaN only.
/// 300 walks at τ = 5: N = 1 with probability e^−5 = 0.0067 (about 2 walks; more than
/// 100 of them has probability far below 1e-100), so at least 200 walks with N ≥ 2 are
/// asked for.
#[test]
fn a_non_finite_later_output_is_reported_too() {
    let mut m = random_models(4, 1.0);
    let head = m.path.layers.last_mut().unwrap();
    let mut bias = head.bias.clone();
    bias[2] = f32::NAN;
    *head = Dense::new(head.inputs, head.outputs, head.weight.clone(), bias);
    let mut multiple = 0u32;
    for s in 0..300u64 {
        let mut rng = WalkRng::from_seed(s);
        let (w, bad) = m.sample_walk_checked(5.0, 0.3, 0.99, true, &mut rng);
        assert_eq!(bad, !w.single, "seed {s}: N = {}", w.n);
        multiple += u32::from(!w.single);
    }
    assert!(multiple >= 200, "only {multiple} of 300 walks had N ≥ 2");
}
