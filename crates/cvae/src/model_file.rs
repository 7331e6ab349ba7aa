//! The model file: the three decoders, their standardisation, the training ranges and a
//! checksum, in a few KiB. Read without burn by the renderers and tests.
//!
//! Layout (little endian): magic `STCVAEMD` (8) | version u32 | metadata length u32 |
//! metadata (JSON, [`Metadata`]) | weights (f32; per model, per layer: W row-major
//! `[out][in]`, then b) | CRC-32 of all preceding bytes (u32).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::decoder::{Decoder, Dense, MAX_HIDDEN_LAYERS, MAX_INPUT, MAX_WIDTH};
use crate::features;

pub const MAGIC: &[u8; 8] = b"STCVAEMD";
pub const VERSION: u32 = 1;

#[derive(Debug, Error)]
pub enum ModelError {
    // Not named `source`: the message already carries the I/O error, and a source would
    // make error chains print it twice.
    #[error("{path}: {err}")]
    Io { path: PathBuf, err: std::io::Error },
    #[error("{path}: not an stcvae model file (bad magic bytes)")]
    BadMagic { path: PathBuf },
    #[error(
        "{path}: model file version {found} is not supported (this build reads version {supported})"
    )]
    Version {
        path: PathBuf,
        found: u32,
        supported: u32,
    },
    #[error(
        "{path}: the model file has {found} bytes where its header promises {}{expected}: truncated, padded or damaged in its header",
        if *.at_least { "at least " } else { "" }
    )]
    Truncated {
        path: PathBuf,
        expected: usize,
        found: usize,
        /// Only the header (not yet the weights' shapes) was read: the file needs at least
        /// `expected` bytes (a file cut inside its JSON read as promising that many).
        at_least: bool,
    },
    #[error("{path}: checksum mismatch: the model file is corrupt")]
    Checksum { path: PathBuf },
    #[error("{path}: invalid model: {msg}")]
    Invalid { path: PathBuf, msg: String },
}

/// How the single-scattering walks (N = 1) are produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SingleScattering {
    /// Drawn analytically with probability e^{−τ}; the models learn N ≥ 2 only.
    Exact,
    /// The paper's way: the models learn all walks, N = 1 included.
    Learned,
}

impl SingleScattering {
    /// The name a training config and a model file's metadata use.
    pub fn name(self) -> &'static str {
        match self {
            SingleScattering::Exact => "exact",
            SingleScattering::Learned => "learned",
        }
    }
}

/// Architecture and standardisation of one decoder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DecoderSpec {
    pub name: String,
    pub cond: usize,
    pub latent: usize,
    pub out: usize,
    pub hidden: Vec<usize>,
    pub cond_shift: Vec<f32>,
    pub cond_scale: Vec<f32>,
    pub out_shift: Vec<f32>,
    pub out_scale: Vec<f32>,
}

/// What the models were trained on: renderers warn when asked for conditions outside.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingInfo {
    pub tau_range: [f64; 2],
    pub g_range: [f64; 2],
    pub albedo_range: [f64; 2],
    /// Free-form provenance: dataset, steps, seconds, config.
    #[serde(default)]
    pub notes: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Metadata {
    pub feature_version: u32,
    pub single_scattering: SingleScattering,
    pub training: TrainingInfo,
    /// LengthGen, PathGen, EventGen, in this order.
    pub decoders: Vec<DecoderSpec>,
}

/// The three decoders, ready to evaluate.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelSet {
    /// The feature version the decoders were trained with ([`features::FEATURE_VERSION`]
    /// for a new file; an older file keeps its own, which says how to read its EventGen).
    pub feature_version: u32,
    pub single_scattering: SingleScattering,
    pub training: TrainingInfo,
    pub length: Decoder,
    pub path: Decoder,
    pub event: Decoder,
}

const NAMES: [&str; 3] = ["lengthgen", "pathgen", "eventgen"];
const SHAPES: [(usize, usize); 3] = [
    (features::LENGTH_COND, features::LENGTH_OUT),
    (features::PATH_COND, features::PATH_OUT),
    (features::EVENT_COND, features::EVENT_OUT),
];

fn spec_of(name: &str, d: &Decoder) -> DecoderSpec {
    DecoderSpec {
        name: name.into(),
        cond: d.cond,
        latent: d.latent,
        out: d.out,
        hidden: d.layers[..d.layers.len() - 1]
            .iter()
            .map(|l| l.outputs)
            .collect(),
        cond_shift: d.cond_shift.clone(),
        cond_scale: d.cond_scale.clone(),
        out_shift: d.out_shift.clone(),
        out_scale: d.out_scale.clone(),
    }
}

impl ModelSet {
    /// How EventGen's output holds the event's distance from the centre.
    pub fn event_radial(&self) -> features::EventRadial {
        features::EventRadial::of_version(self.feature_version)
            .expect("a ModelSet holds a feature version this build reads")
    }

    /// The three decoders, named in [`Self::DECODER_NAMES`]'s order.
    pub fn decoders(&self) -> [&Decoder; 3] {
        [&self.length, &self.path, &self.event]
    }

    /// The names of [`Self::decoders`], in its order, for messages and tables.
    pub const DECODER_NAMES: [&'static str; 3] = ["LengthGen", "PathGen", "EventGen"];

    /// Serialises to the file layout.
    pub fn to_bytes(&self) -> Vec<u8> {
        let meta = Metadata {
            feature_version: self.feature_version,
            single_scattering: self.single_scattering,
            training: self.training.clone(),
            decoders: NAMES
                .iter()
                .zip(self.decoders())
                .map(|(n, d)| spec_of(n, d))
                .collect(),
        };
        let json = serde_json::to_vec(&meta).expect("metadata serialises");
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(&json);
        for d in self.decoders() {
            for l in &d.layers {
                for v in l.weight.iter().chain(&l.bias) {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        let crc = crc32fast::hash(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        out
    }

    /// Writes the file atomically.
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        scatter_sim::output::write_atomic(path, &self.to_bytes()).map_err(|e| ModelError::Io {
            path: path.into(),
            err: e,
        })
    }

    /// Reads and validates a model file. The magic bytes and the size are looked at before
    /// the rest is read: `--model data/train.bin` (a dataset, hundreds of MB) used to be
    /// read whole only to be refused for its first eight bytes.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        use std::io::Read;
        let io = |e| ModelError::Io {
            path: path.into(),
            err: e,
        };
        scatter_sim::output::check_input(path).map_err(io)?;
        let meta = std::fs::metadata(path).map_err(io)?;
        if meta.is_dir() {
            return Err(io(std::io::Error::other(
                "is a directory, not a model file",
            )));
        }
        let len = meta.len();
        if len == 0 {
            // "bad magic bytes" for a file with no bytes read as damage; an empty file is
            // more often a failed download or copy.
            return Err(ModelError::Invalid {
                path: path.into(),
                msg: "the file is empty, not a model file".into(),
            });
        }
        if len < 8 {
            return Err(ModelError::BadMagic { path: path.into() });
        }
        let mut file = std::fs::File::open(path).map_err(io)?;
        let mut magic = [0u8; 8];
        file.read_exact(&mut magic).map_err(io)?;
        if &magic != MAGIC {
            return Err(ModelError::BadMagic { path: path.into() });
        }
        if len > MAX_FILE_BYTES {
            return Err(ModelError::Invalid {
                path: path.into(),
                msg: format!(
                    "the file has {len} bytes, more than any model file this build writes \
                     (at most {MAX_FILE_BYTES}: three decoders of at most {MAX_HIDDEN_LAYERS} \
                     layers of width {MAX_WIDTH})"
                ),
            });
        }
        let mut bytes = magic.to_vec();
        file.read_to_end(&mut bytes).map_err(io)?;
        Self::from_bytes(&bytes, path)
    }

    /// Parses and validates: magic, version, checksum, metadata, shapes, finite values.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, ModelError> {
        let p = || path.to_path_buf();
        let invalid = |msg: String| ModelError::Invalid { path: p(), msg };
        let json_len = check_frame(bytes, path)?;
        let body = &bytes[..bytes.len() - 4];
        let stored = u32::from_le_bytes(bytes[bytes.len() - 4..].try_into().unwrap());
        let meta: Result<Metadata, _> = serde_json::from_slice(&bytes[16..16 + json_len]);
        // Size check first (a truncated file fails the checksum too, but "truncated" is
        // the more useful message), which needs the metadata.
        if let Ok(m) = &meta
            && let Some(expected) = weight_count(m)
                .and_then(|n| n.checked_mul(4))
                .and_then(|n| n.checked_add(16 + json_len + 4))
            && expected != bytes.len()
            && m.decoders.len() == 3
            // A decoder refused for its depth below is named for that, not for the size
            // its layers would need.
            && m.decoders.iter().all(|d| d.hidden.len() <= MAX_HIDDEN_LAYERS)
        {
            return Err(ModelError::Truncated {
                path: p(),
                expected,
                found: bytes.len(),
                at_least: false,
            });
        }
        if crc32fast::hash(body) != stored {
            return Err(ModelError::Checksum { path: p() });
        }
        let meta = meta.map_err(|e| invalid(format!("metadata: {e}")))?;
        check_training(&meta.training).map_err(invalid)?;
        if features::EventRadial::of_version(meta.feature_version).is_none() {
            return Err(invalid(format!(
                "feature version {} (this build reads {} to {})",
                meta.feature_version,
                features::OLDEST_FEATURE_VERSION,
                features::FEATURE_VERSION
            )));
        }
        if meta.decoders.len() != 3 {
            return Err(invalid(format!(
                "{} decoders, expected 3",
                meta.decoders.len()
            )));
        }
        let mut floats = body[16 + json_len..]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()));
        let mut decoders = Vec::with_capacity(3);
        for (i, spec) in meta.decoders.iter().enumerate() {
            decoders.push(read_decoder(i, spec, &mut floats).map_err(invalid)?);
        }
        for d in &mut decoders {
            lift_old_floor(&mut d.cond_scale);
            lift_old_floor(&mut d.out_scale);
        }
        let event = decoders.pop().unwrap();
        let path_d = decoders.pop().unwrap();
        let length = decoders.pop().unwrap();
        let set = Self {
            feature_version: meta.feature_version,
            single_scattering: meta.single_scattering,
            training: meta.training,
            length,
            path: path_d,
            event,
        };
        set.check_length_decoder()
            .map_err(|e| invalid(format!("lengthgen: {e}")))?;
        set.check_finite_heads().map_err(invalid)?;
        Ok(set)
    }

    /// PathGen's and EventGen's heads are finite over a grid of their inputs: τ and g as
    /// [`Self::check_length_decoder`] probes them, relative log N −2, 0, 2, an exit at
    /// the pole and one at the equator, the training range's albedos, at the latent mean
    /// and [`PROBE_LATENT`] out along each latent axis. The samplers replace a non-finite
    /// output by a fixed valid one, so a file whose weights (each within its bound)
    /// overflow to inf, then NaN, loaded and rendered a plausible, wrong image (every exit
    /// at α = β = 0) without a word.
    fn check_finite_heads(&self) -> Result<(), String> {
        let conditions: Vec<_> = probe_media(&self.training)
            .into_iter()
            .flat_map(|(tau, g)| {
                self.training
                    .albedo_range
                    .map(|albedo| features::WalkFeatures::new(tau, g, albedo))
            })
            .collect();
        let finite = |d: &crate::decoder::Decoder, cond: &[f64], z: &[f32]| {
            let head = d.head(&d.draw(cond, z, &[0.0; crate::decoder::MAX_OUT]));
            head[..2 * d.out].iter().all(|h| h.is_finite())
        };
        for f in &conditions {
            for rel in [-2.0, 0.0, 2.0] {
                let path = f.path_cond(rel);
                for (name, d, cond) in [
                    ("pathgen", &self.path, &path[..]),
                    (
                        "eventgen",
                        &self.event,
                        &f.event_cond(rel, 1.0, 0.0, 0.0)[..],
                    ),
                    (
                        "eventgen",
                        &self.event,
                        &f.event_cond(rel, 0.0, 0.5, 0.5)[..],
                    ),
                ] {
                    if let Some(z) = latent_probes(d.latent).find(|z| !finite(d, cond, z)) {
                        return Err(format!(
                            "{name}: its output is not finite at conditions {cond:?} and \
                             latent {z:?} (a damaged or hand-edited file)"
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// LengthGen's median and spread of the relative log N over a 3 × 3 grid of its
    /// training range (τ spaced in ln(1 + τ)), at the latent mean and
    /// [`PROBE_LATENT`] standard deviations out along each latent axis.
    ///
    /// Weights and standardisation each within their bounds can still decode N = e^100
    /// (capped at 1e15), and NEE through EventGen weighs a walk's every event: such a file
    /// rendered an image of 1e13 without a word. The simulator's walks have a median
    /// relative log N within about ±1 and a spread below 1 (docs/TRAINING.md), so a file
    /// beyond ±[`MAX_RELATIVE_LOG_N`] or a spread above [`MAX_LOG_N_SPREAD`] is damaged
    /// or hand-edited, never merely under-trained (training starts from the data's own
    /// mean and spread). The latent mean alone was not enough: a file whose latent
    /// weights were 10⁴ (within every bound) decoded well at z = 0 and a mean N of 2·10⁹
    /// elsewhere, an image of 5·10⁶. The shipped model's medians stay within ±1.9 and its
    /// spreads below 1 at every probe.
    pub fn check_length_decoder(&self) -> Result<(), String> {
        for z in latent_probes(self.length.latent) {
            for (tau, g) in probe_media(&self.training) {
                self.check_length_probe(tau, g, &z)?;
            }
        }
        Ok(())
    }

    /// One probe of [`Self::check_length_decoder`].
    fn check_length_probe(&self, tau: f64, g: f64, z: &[f32]) -> Result<(), String> {
        let cond = features::WalkFeatures::new(tau, g, 1.0).length_cond();
        let head = self.length.head(&self.length.draw(&cond, z, &[0.0]));
        let (scale, shift) = (
            self.length.out_scale[0] as f64,
            self.length.out_shift[0] as f64,
        );
        let median = head[0] as f64 * scale + shift;
        let logvar = head[1].clamp(-crate::decoder::LOGVAR_CLAMP, crate::decoder::LOGVAR_CLAMP);
        let spread = scale * (0.5 * logvar as f64).exp();
        if median.abs() <= MAX_RELATIVE_LOG_N && spread <= MAX_LOG_N_SPREAD {
            return Ok(());
        }
        let at = if z.iter().all(|&x| x == 0.0) {
            String::new()
        } else {
            format!(" and latent {z:?}")
        };
        Err(format!(
            "at τ = {}, g = {}{at} it decodes ln N = ln(diffusion count) + {median:.1} ± \
             {spread:.1} (median ± spread); trained models stay within ±{MAX_RELATIVE_LOG_N} \
             and a spread of {MAX_LOG_N_SPREAD} (a damaged or hand-edited file)",
            significant(tau),
            significant(g)
        ))
    }
}

/// The load probes' media: a 3 × 3 grid of the training range's (τ, g), τ spaced in
/// ln(1 + τ).
fn probe_media(t: &TrainingInfo) -> Vec<(f64, f64)> {
    let (lo, hi) = (t.tau_range[0].ln_1p(), t.tau_range[1].ln_1p());
    let mut media = Vec::with_capacity(9);
    for i in 0..3 {
        let tau = (lo + (hi - lo) * i as f64 / 2.0).exp_m1();
        for j in 0..3 {
            media.push((
                tau,
                t.g_range[0] + (t.g_range[1] - t.g_range[0]) * j as f64 / 2.0,
            ));
        }
    }
    media
}

/// The probes' latent points: the mean, then [`PROBE_LATENT`] out along each axis, + and −.
fn latent_probes(latent: usize) -> impl Iterator<Item = Vec<f32>> {
    (0..=2 * latent).map(move |k| {
        let mut z = vec![0f32; latent];
        if k > 0 {
            let sign = if k % 2 == 1 { 1.0 } else { -1.0 };
            z[(k - 1) / 2] = sign * PROBE_LATENT;
        }
        z
    })
}

/// How far out along each latent axis [`ModelSet::check_length_decoder`] probes, in
/// standard deviations of the latent prior (draws beyond it: 0.3 %).
pub const PROBE_LATENT: f32 = 3.0;
/// Bounds of [`ModelSet::check_length_decoder`], in units of ln N.
pub const MAX_RELATIVE_LOG_N: f64 = 8.0;
pub const MAX_LOG_N_SPREAD: f64 = 4.0;

/// τ and g of a probe point, short and exact enough to repeat on the command line.
fn significant(x: f64) -> String {
    let s = format!("{x:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Bounds on a decoder's standardisation: every feature it reads or writes is O(1) to
/// O(10) (ln(1 + τ) ≤ 7, g and the albedo feature in [−1, 1], log N relative to the
/// diffusion scale, the output maps' real lines: docs/TRAINING.md), so a shift beyond
/// ±MAX_NORM or a scale above it is a damaged or hand-edited file, which would decode
/// absurd walks (N = 2^32 − 1) into a bright image without an error. Training writes no
/// scale below MIN_SCALE: a column with less spread gets scale 1 (train/data.rs's
/// `MIN_SPREAD`, defined from it).
pub const MAX_NORM: f32 = 100.0;
pub const MIN_SCALE: f32 = 1e-6;

/// Reads the scale older builds gave a column without spread, 10⁻⁶ (exactly
/// [`MIN_SCALE`]), as today's 1. Decoded with 10⁻⁶, any condition off the training value
/// reached the network a million times larger (a g = 0.875 model decoded N = 2 for every
/// walk at g = 0.4: a render 26 % too bright); the training rows sat at 0 either way, so
/// the decode is the one a model trained today gives. An output's 10⁻⁶ likewise (its
/// targets sat at 0). Model files, `--base` inputs and checkpoint records all pass here.
pub fn lift_old_floor(scales: &mut [f32]) {
    for v in scales.iter_mut().filter(|v| **v == MIN_SCALE) {
        *v = 1.0;
    }
}

/// Checks the shifts and scales of a decoder with `cond` inputs and `out` outputs, naming
/// the first field out of its range.
fn check_standardisation(spec: &DecoderSpec, cond: usize, out: usize) -> Result<(), String> {
    check_norm(
        [
            &spec.cond_shift,
            &spec.cond_scale,
            &spec.out_shift,
            &spec.out_scale,
        ],
        cond,
        out,
    )
}

/// [`check_standardisation`] on the four vectors (cond shift and scale, out shift and
/// scale) wherever they are kept: a training checkpoint's record holds them too, and an
/// edited one was reported only when the model file was written, under its name.
pub(crate) fn check_norm(v: [&[f32]; 4], cond: usize, out: usize) -> Result<(), String> {
    for (name, v, n, is_scale) in [
        ("cond_shift", v[0], cond, false),
        ("cond_scale", v[1], cond, true),
        ("out_shift", v[2], out, false),
        ("out_scale", v[3], out, true),
    ] {
        if v.len() != n {
            return Err(format!("{name} has {} values, expected {n}", v.len()));
        }
        for (i, x) in v.iter().enumerate() {
            let ok = if is_scale {
                (MIN_SCALE..=MAX_NORM).contains(x)
            } else {
                x.abs() <= MAX_NORM
            };
            if !ok {
                let range = if is_scale {
                    format!("[{MIN_SCALE:e}, {MAX_NORM}]")
                } else {
                    format!("[-{MAX_NORM}, {MAX_NORM}]")
                };
                return Err(format!(
                    "{name}[{i}] = {} is out of range: allowed {range}",
                    scatter_sim::ranges::num(*x)
                ));
            }
        }
    }
    Ok(())
}

/// Largest weight magnitude accepted. Trained decoders' weights are O(1); far larger ones
/// mean a corrupt file and would overflow f32 activations into NaN samples.
pub const MAX_WEIGHT: f32 = 1e4;

/// A bound on a model file's size: the weights of three decoders at the largest allowed
/// shape (~0.5 MB) and metadata, with room to spare. Anything larger is not a model file.
pub const MAX_FILE_BYTES: u64 = 16 << 20;

/// The training ranges steer the renderers' warnings and the sphere-step cap (τ_max), so
/// they must be ordered and inside the project's parameter ranges.
/// The training ranges a model file may hold (`train` checks its dataset's before
/// training).
pub fn check_training(t: &TrainingInfo) -> Result<(), String> {
    check_ranges(
        [
            "training.tau_range",
            "training.g_range",
            "training.albedo_range",
        ],
        [t.tau_range, t.g_range, t.albedo_range],
    )
}

/// τ, g and albedo ranges (`names` are their fields, for the message) ordered and inside
/// the project's parameter ranges: a model file's, or a training checkpoint's, whose
/// ranges become the file's.
pub fn check_ranges(names: [&str; 3], [tau, g, albedo]: [[f64; 2]; 3]) -> Result<(), String> {
    use scatter_sim::ranges::{G_MAX, TAU_LIMIT};
    // The slack absorbs the f32 storage of the training rows' g (0.999f32 > 0.999); the
    // other ends (0, 1, 1000) are exact in f32.
    let ok = |r: [f64; 2], lo: f64, hi: f64| lo <= r[0] && r[0] <= r[1] && r[1] <= hi;
    let slack = 1e-6;
    if !(ok(tau, 0.0, TAU_LIMIT) && tau[1] > 0.0) {
        return Err(format!(
            "{} = {tau:?}: expected 0 <= lo <= hi <= {TAU_LIMIT}, hi > 0",
            names[0]
        ));
    }
    if !ok(g, -G_MAX - slack, G_MAX + slack) {
        return Err(format!(
            "{} = {g:?}: expected -{G_MAX} <= lo <= hi <= {G_MAX}",
            names[1]
        ));
    }
    if !ok(albedo, 0.0, 1.0) {
        return Err(format!(
            "{} = {albedo:?}: expected 0 <= lo <= hi <= 1",
            names[2]
        ));
    }
    Ok(())
}

/// The number of weights the metadata promises; None when it overflows (the metadata is
/// not validated yet, and the width checks that follow give the better message).
fn weight_count(m: &Metadata) -> Option<usize> {
    m.decoders.iter().try_fold(0usize, |acc, d| {
        let widths: Vec<usize> = std::iter::once(d.cond.checked_add(d.latent)?)
            .chain(d.hidden.iter().copied())
            .chain(std::iter::once(d.out.checked_mul(2)?))
            .collect();
        widths.windows(2).try_fold(acc, |acc, w| {
            acc.checked_add(w[0].checked_mul(w[1])?.checked_add(w[1])?)
        })
    })
}

/// Checks the file's frame (magic, version, the metadata's length within the file) and
/// returns the metadata's length.
fn check_frame(bytes: &[u8], path: &Path) -> Result<usize, ModelError> {
    let p = || path.to_path_buf();
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(ModelError::BadMagic { path: p() });
    }
    if bytes.len() < 20 {
        return Err(ModelError::Truncated {
            path: p(),
            expected: 20,
            found: bytes.len(),
            at_least: true,
        });
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
    if version != VERSION {
        return Err(ModelError::Version {
            path: p(),
            found: version,
            supported: VERSION,
        });
    }
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    if 16 + json_len + 4 > bytes.len() {
        return Err(ModelError::Truncated {
            path: p(),
            expected: 16 + json_len + 4,
            found: bytes.len(),
            at_least: true,
        });
    }
    Ok(json_len)
}

/// Decoder `i` of the file: its shape checked against the one this build reads, its
/// standardisation, and its layers' weights (each finite and within the bound) read from
/// `floats`.
fn read_decoder(
    i: usize,
    spec: &DecoderSpec,
    floats: &mut impl Iterator<Item = f32>,
) -> Result<Decoder, String> {
    let (cond, out) = SHAPES[i];
    if spec.name != NAMES[i] || spec.cond != cond || spec.out != out {
        return Err(format!(
            "decoder {i} is '{}' with {} inputs and {} outputs; expected '{}' with {cond} and {out}",
            spec.name, spec.cond, spec.out, NAMES[i]
        ));
    }
    let widths: Vec<usize> = std::iter::once(spec.cond.saturating_add(spec.latent))
        .chain(spec.hidden.iter().copied())
        .chain(std::iter::once(spec.out.saturating_mul(2)))
        .collect();
    if spec.cond.saturating_add(spec.latent) > MAX_INPUT {
        return Err(format!(
            "{}: {} conditions + {} latent inputs; at most {MAX_INPUT} in all",
            spec.name, spec.cond, spec.latent
        ));
    }
    if spec.hidden.len() > MAX_HIDDEN_LAYERS {
        return Err(format!(
            "{}: {} hidden layers; at most {MAX_HIDDEN_LAYERS}",
            spec.name,
            spec.hidden.len()
        ));
    }
    if widths.iter().any(|&w| w == 0 || w > MAX_WIDTH) {
        return Err(format!(
            "{}: layer widths {widths:?} out of range: allowed [1, {MAX_WIDTH}] each",
            spec.name
        ));
    }
    check_standardisation(spec, cond, out).map_err(|e| format!("{}: {e}", spec.name))?;
    let mut layers = Vec::new();
    for w in widths.windows(2) {
        let (inputs, outputs) = (w[0], w[1]);
        let weight: Vec<f32> = floats.by_ref().take(inputs * outputs).collect();
        let bias: Vec<f32> = floats.by_ref().take(outputs).collect();
        if weight.len() != inputs * outputs || bias.len() != outputs {
            return Err("weights end early".into());
        }
        if !weight.iter().chain(&bias).all(|v| v.abs() <= MAX_WEIGHT) {
            return Err(format!(
                "{}: a weight is non-finite or beyond ±{MAX_WEIGHT:e}",
                spec.name
            ));
        }
        layers.push(Dense::new(inputs, outputs, weight, bias));
    }
    Ok(Decoder {
        cond,
        latent: spec.latent,
        out,
        layers,
        cond_shift: spec.cond_shift.clone(),
        cond_scale: spec.cond_scale.clone(),
        out_shift: spec.out_shift.clone(),
        out_scale: spec.out_scale.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The load checks probe the training range's corners and middle: a file absurd only
    /// at τ_max or at either end of g must meet a probe. For τ ∈ [0, 300] the middle in
    /// ln(1 + τ) is √301 − 1 (ln(1 + τ) = ln(301)/2), for g ∈ [−0.9, 0.9] it is 0; the
    /// nine probes are their 3 × 3 grid, each once.
    #[test]
    fn the_probes_span_the_training_range() {
        let t = TrainingInfo {
            tau_range: [0.0, 300.0],
            g_range: [-0.9, 0.9],
            albedo_range: [0.5, 1.0],
            notes: String::new(),
        };
        let media = probe_media(&t);
        assert_eq!(media.len(), 9);
        for tau in [0.0, 301f64.sqrt() - 1.0, 300.0] {
            for g in [-0.9, 0.0, 0.9] {
                let found = media
                    .iter()
                    .filter(|&&(a, b)| {
                        (a - tau).abs() <= 1e-9 * (1.0 + tau) && (b - g).abs() <= 1e-12
                    })
                    .count();
                assert_eq!(found, 1, "(τ, g) = ({tau}, {g}) in {media:?}");
            }
        }
    }
}
