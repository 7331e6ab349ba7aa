//! A model's training settings (a `[lengthgen]`, `[pathgen]` or `[eventgen]` table of the
//! training config): their readers, ranges and the learning-rate schedule.

use serde::{Deserialize, Serialize};

use scatter_sim::ranges::{num, whole_in, whole_list_in, whole_range};

use super::network::Architecture;

/// Training settings of one model (a `[lengthgen]`, `[pathgen]` or `[eventgen]` table
/// of the training config).
/// (Its absent options are not serialized as null, which their readers refuse.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    #[serde(deserialize_with = "read_latent")]
    pub latent: usize,
    #[serde(deserialize_with = "read_hidden")]
    pub hidden: Vec<usize>,
    #[serde(
        default,
        deserialize_with = "read_encoder_hidden",
        skip_serializing_if = "Option::is_none"
    )]
    pub encoder_hidden: Option<Vec<usize>>,
    #[serde(deserialize_with = "read_steps")]
    pub steps: u64,
    #[serde(default = "default_batch", deserialize_with = "read_batch")]
    pub batch_size: usize,
    /// Peak learning rate (after warm-up).
    pub lr: f64,
    /// Learning rate at the last step (cosine decay from `lr`).
    pub lr_final: f64,
    /// Linear warm-up steps; default: 500, or a quarter of `steps` when that is fewer.
    #[serde(
        default,
        deserialize_with = "read_warmup",
        skip_serializing_if = "Option::is_none"
    )]
    pub warmup: Option<u64>,
}

/// Most rows a training batch may have (its activations' memory is bounded again by
/// [`MAX_BATCH_FLOATS`]).
pub const MAX_BATCH: usize = 1 << 20;

/// Widest layer an encoder may have.
pub const MAX_ENCODER_WIDTH: usize = 1024;

// The whole-number fields read with their own ranges, so that a value the type cannot
// hold (`batch_size = -1`) is refused with the range `validate` then checks ("[1,
// 1048576]"), not the type's ("at least 0", where 0 is refused as well).
fn read_latent<'de, D: serde::Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    whole_in(d, 1, crate::decoder::MAX_LATENT as u64)
}

fn read_hidden<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<usize>, D::Error> {
    whole_list_in(d, 1, crate::decoder::MAX_WIDTH as u64)
}

fn read_encoder_hidden<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Option<Vec<usize>>, D::Error> {
    whole_list_in(d, 1, MAX_ENCODER_WIDTH as u64).map(Some)
}

fn read_steps<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    whole_in(d, 1, MAX_STEPS)
}

fn read_batch<'de, D: serde::Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    whole_in(d, 1, MAX_BATCH as u64)
}

fn read_warmup<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
    whole_in(d, 0, MAX_STEPS).map(Some)
}

fn default_batch() -> usize {
    1024
}

const DEFAULT_WARMUP: u64 = 500;

/// Most hidden layers an encoder may have (the decoders': [`crate::decoder::MAX_HIDDEN_LAYERS`]).
pub const MAX_ENCODER_LAYERS: usize = 8;

/// Most floats one layer's activations may hold in a training batch (batch × width).
pub const MAX_BATCH_FLOATS: usize = 1 << 25;

impl ModelConfig {
    pub fn architecture(&self) -> Architecture {
        Architecture {
            latent: self.latent,
            hidden: self.hidden.clone(),
            encoder_hidden: self.encoder_hidden.clone(),
        }
    }

    /// The warm-up's length: as given, else the default (at most a quarter of the run, so
    /// that a short run without a `warmup` line still reaches `lr` and decays).
    pub fn warmup(&self) -> u64 {
        self.warmup.unwrap_or(DEFAULT_WARMUP.min(self.steps / 4))
    }

    /// Linear warm-up to `lr`, then cosine decay that would reach `lr_final` at step
    /// `steps`, one past the last step taken (steps count from 0): the last step's rate is
    /// above `lr_final` by (lr − lr_final)·(π/2)²/(steps − warmup)², nothing a run
    /// notices, and the shipped model was trained so.
    pub fn learning_rate(&self, step: u64) -> f64 {
        let warmup = self.warmup();
        if step < warmup {
            return self.lr * (step + 1) as f64 / warmup as f64;
        }
        let span = (self.steps.saturating_sub(warmup)).max(1) as f64;
        let t = ((step - warmup) as f64 / span).min(1.0);
        self.lr_final + 0.5 * (self.lr - self.lr_final) * (1.0 + (std::f64::consts::PI * t).cos())
    }

    pub fn validate(&self, name: &str) -> Result<(), String> {
        let bad = |f: &str, why: &str| Err(format!("{name}.{f}: {why}"));
        if self.steps == 0 || self.steps > MAX_STEPS {
            return bad(
                "steps",
                &format!(
                    "{} is out of range: allowed {} (0 would train nothing and export an \
                     untrained model)",
                    self.steps,
                    whole_range(1, MAX_STEPS)
                ),
            );
        }
        if self.latent == 0 || self.latent > crate::decoder::MAX_LATENT {
            return bad(
                "latent",
                &format!(
                    "{} is out of range: allowed {}",
                    self.latent,
                    whole_range(1, crate::decoder::MAX_LATENT as u64)
                ),
            );
        }
        if let Some(why) = layers_out_of_range(
            &self.hidden,
            crate::decoder::MAX_HIDDEN_LAYERS,
            crate::decoder::MAX_WIDTH,
        ) {
            return bad("hidden", &why);
        }
        // Depth bounded too: the batch check below is per tensor, and 64 layers of 1,024
        // at the largest batch it allows asked tens of GiB and aborted on allocation.
        if let Some(why) = self
            .encoder_hidden
            .as_deref()
            .and_then(|e| layers_out_of_range(e, MAX_ENCODER_LAYERS, MAX_ENCODER_WIDTH))
        {
            return bad("encoder_hidden", &why);
        }
        // A batch's activations are batch_size × widest layer floats per layer; beyond
        // 2^20 rows the gradients average out anyway and the memory does not.
        if self.batch_size == 0 || self.batch_size > MAX_BATCH {
            return bad(
                "batch_size",
                &format!(
                    "{} is out of range: allowed {}",
                    self.batch_size,
                    whole_range(1, MAX_BATCH as u64)
                ),
            );
        }
        // Each layer's activations and their gradients hold batch_size × width floats: a
        // batch of 2^20 with 1,024-wide encoder layers asked 4 GiB per tensor and aborted
        // on allocation. 2^25 floats (128 MiB a tensor) keeps a step within a few GiB.
        let widest = self
            .hidden
            .iter()
            .chain(self.encoder_hidden.iter().flatten())
            .copied()
            .max()
            .unwrap_or(1);
        let floats = self.batch_size.saturating_mul(widest);
        if floats > MAX_BATCH_FLOATS {
            return bad(
                "batch_size",
                &format!(
                    "{} × the widest layer's {widest} = {floats} floats a tensor, beyond \
                     {MAX_BATCH_FLOATS} (2^25): lower batch_size or the layer widths",
                    self.batch_size
                ),
            );
        }
        if !(self.lr > 0.0 && self.lr < 1.0) {
            return bad(
                "lr",
                &format!("{} is out of range: allowed (0, 1)", num(self.lr)),
            );
        }
        if !(self.lr_final >= 0.0 && self.lr_final <= self.lr) {
            return bad(
                "lr_final",
                &format!(
                    "{} is out of range: allowed [0, lr = {}]",
                    num(self.lr_final),
                    num(self.lr)
                ),
            );
        }
        // A warm-up longer than the run never reaches lr, nor decays to lr_final.
        if let Some(w) = self.warmup
            && w > self.steps
        {
            return bad(
                "warmup",
                &format!("{w} is out of range: allowed [0, steps = {}]", self.steps),
            );
        }
        Ok(())
    }
}

/// Why a list of layer widths is refused, naming the part that is wrong (the count, or the
/// first width out of range) so that a long list is not echoed whole.
fn layers_out_of_range(widths: &[usize], max_layers: usize, max_width: usize) -> Option<String> {
    let allowed = format!(
        "allowed {} layers, each of width {}",
        whole_range(1, max_layers as u64),
        whole_range(1, max_width as u64)
    );
    if widths.is_empty() || widths.len() > max_layers {
        return Some(format!("{} layers, out of range: {allowed}", widths.len()));
    }
    let (i, w) = widths
        .iter()
        .enumerate()
        .find(|&(_, &w)| w == 0 || w > max_width)?;
    Some(format!(
        "width {w} (layer {}) is out of range: {allowed}",
        i + 1
    ))
}

/// The most steps a model may train for, as configured or after `--steps-scale`, and so
/// the most a checkpoint record may say it has taken (`CheckpointInfo::check`). At
/// ~1 µs a step 2^40 is 13 days; the bound keeps step counts exact in f64 and in the
/// learning-rate schedule.
pub const MAX_STEPS: u64 = 1 << 40;

/// A small model's settings for the crate's tests.
#[cfg(test)]
pub(super) fn config(steps: u64, warmup: Option<u64>) -> ModelConfig {
    ModelConfig {
        latent: 2,
        hidden: vec![4],
        encoder_hidden: None,
        steps,
        batch_size: 8,
        lr: 1e-2,
        lr_final: 1e-4,
        warmup,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A config written out reads back as it was, its absent options included (written as
    /// null, they were refused by the range-checking readers), and a negative width or
    /// batch is refused with the field's range.
    #[test]
    fn a_model_config_round_trips_and_states_its_ranges() {
        for c in [config(100, None), config(100, Some(7))] {
            let text = serde_json::to_string(&c).unwrap();
            assert_eq!(
                serde_json::from_str::<ModelConfig>(&text).unwrap(),
                c,
                "{text}"
            );
        }
        let bad = |json: &str| {
            serde_json::from_str::<ModelConfig>(json)
                .unwrap_err()
                .to_string()
        };
        let base = r#""latent": 2, "steps": 10, "lr": 0.01, "lr_final": 0.001"#;
        let e = bad(&format!(r#"{{{base}, "hidden": [4, -1]}}"#));
        assert!(e.contains("expected a whole number in [1, 64]"), "{e}");
        let e = bad(&format!(r#"{{{base}, "hidden": [4], "batch_size": -1}}"#));
        assert!(e.contains("expected a whole number in [1, 1048576]"), "{e}");
    }

    /// Without a `warmup` line a short run warms up over a quarter of its steps (the
    /// default 500 would outlast it: lr never reached, never decayed); a given warm-up
    /// longer than the run is refused, naming the model and the field.
    #[test]
    fn the_warm_up_fits_the_run() {
        let short = config(100, None);
        assert_eq!(short.warmup(), 25);
        assert!(short.validate("m").is_ok());
        assert_eq!(short.learning_rate(24), 1e-2);
        assert!((short.learning_rate(100) - 1e-4).abs() < 1e-12);
        assert!(short.learning_rate(60) < 1e-2 && short.learning_rate(60) > 1e-4);
        assert_eq!(config(100_000, None).warmup(), 500);
        let e = config(100, Some(101)).validate("pathgen").unwrap_err();
        assert_eq!(
            e,
            "pathgen.warmup: 101 is out of range: allowed [0, steps = 100]"
        );
    }

    /// The schedule at its landmarks against the formula worked by hand, with lr = 1e-2,
    /// lr_final = 1e-4 and a warm-up of 25 of 125 steps (a decay over 100): lr/25 = 4e-4
    /// at step 0; lr at the warm-up's last step (24) and at the decay's first (25), never
    /// above it; lr_final + (lr − lr_final)(1 + cos π/4)/2 = 8.550179e-3 a quarter into the
    /// decay (step 50); (lr + lr_final)/2 = 5.05e-3 halfway (step 75); lr_final at step 125.
    /// Within 1e-12 relative: f64 rounding (cos π/2 = 6e-17). The test above checks step 24,
    /// the end and that step 60 lies between the two rates, which a decay from
    /// lr + 2·lr_final (the difference written as a sum: 1.02e-2 at step 25, 5.15e-3 at 75)
    /// passed, as did a warm-up one step too long (lr·26/25 at step 25).
    #[test]
    fn the_schedule_meets_its_landmarks() {
        let c = config(125, Some(25));
        let (lr, fin) = (1e-2, 1e-4);
        for (step, want) in [
            (0, lr / 25.0),
            (24, lr),
            (25, lr),
            (
                50,
                fin + 0.5 * (lr - fin) * (1.0 + std::f64::consts::FRAC_1_SQRT_2),
            ),
            (75, 0.5 * (lr + fin)),
            (125, fin),
        ] {
            let got = c.learning_rate(step);
            assert!(
                (got - want).abs() <= 1e-12 * want,
                "step {step}: {got} against {want}"
            );
        }
        // Rising through the warm-up, falling after it, never above lr.
        for s in 0..125 {
            let (a, b) = (c.learning_rate(s), c.learning_rate(s + 1));
            assert!(a <= lr * (1.0 + 1e-12), "step {s}: {a}");
            if s < 24 {
                assert!(b > a, "warm-up step {s}: {a} then {b}");
            } else {
                assert!(b <= a * (1.0 + 1e-12), "decay step {s}: {a} then {b}");
            }
        }
    }

    /// A refused layer list names its count or its first bad width, not the whole list.
    #[test]
    fn layer_lists_name_what_is_out_of_range() {
        let mut c = config(100, None);
        let allowed = "allowed [1, 8] layers, each of width [1, 64]";
        for (hidden, why) in [
            (vec![], "0 layers, out of range".to_string()),
            (
                vec![16, 0, 16],
                "width 0 (layer 2) is out of range".to_string(),
            ),
            (vec![65], "width 65 (layer 1) is out of range".to_string()),
            (vec![1; 10_000], "10000 layers, out of range".to_string()),
        ] {
            c.hidden = hidden;
            let e = c.validate("lengthgen").unwrap_err();
            assert_eq!(e, format!("lengthgen.hidden: {why}: {allowed}"));
        }
        c.hidden = vec![64; 8];
        assert!(c.validate("lengthgen").is_ok());
    }

    /// A batch whose widest layer's activations would pass 2^25 floats is refused, naming
    /// the field; exactly 2^25 passes.
    #[test]
    fn a_batch_too_large_for_memory_is_refused() {
        let mut c = config(100, None);
        c.hidden = vec![32];
        c.encoder_hidden = Some(vec![1024, 1024]);
        c.batch_size = MAX_BATCH_FLOATS / 1024;
        assert!(c.validate("pathgen").is_ok());
        c.batch_size += 1;
        let e = c.validate("pathgen").unwrap_err();
        assert!(
            e.starts_with("pathgen.batch_size: ") && e.contains("1024"),
            "{e}"
        );
        // The check is per tensor: the depth is bounded apart.
        c.batch_size = MAX_BATCH_FLOATS / 1024;
        c.encoder_hidden = Some(vec![1024; MAX_ENCODER_LAYERS]);
        assert!(c.validate("pathgen").is_ok());
        c.encoder_hidden = Some(vec![1024; MAX_ENCODER_LAYERS + 1]);
        let e = c.validate("pathgen").unwrap_err();
        assert_eq!(
            e,
            "pathgen.encoder_hidden: 9 layers, out of range: allowed [1, 8] layers, each of \
             width [1, 1024]"
        );
    }

    /// A negative final learning rate is refused naming lr_final: the cosine decay would
    /// cross 0 before the run's end and its last steps climb the loss (gradient ascent).
    /// With lr = 1e-2, lr_final = −1e-4 and the default warm-up of 25 of 100 steps, step
    /// 99's rate is −1e-4 + (1.01e-2/2)(1 + cos(74π/75)) = −9.6e-5 < 0, which the schedule
    /// assert below shows. 0 is allowed. (The CLI test refuses only a final rate above lr.)
    #[test]
    fn a_negative_final_learning_rate_is_refused() {
        let mut c = config(100, None);
        c.lr_final = -1e-4;
        assert!(c.learning_rate(99) < 0.0, "{}", c.learning_rate(99));
        let e = c.validate("pathgen").unwrap_err();
        assert!(
            e.starts_with("pathgen.lr_final: ") && e.contains("is out of range: allowed [0, lr = "),
            "{e}"
        );
        c.lr_final = 0.0;
        assert!(c.validate("pathgen").is_ok());
    }

    /// A peak learning rate of 0 or below, or of 1 and above, is refused naming lr: at 0
    /// (with lr_final = 0, which lr_final's own check allows) every step's rate is 0 and the
    /// run exports its untrained network after hours; a negative rate climbs the loss. No
    /// test refused such an lr (the CLI tests only lr_final above lr). Within the range
    /// (lr = 1e-2, lr_final = 0) the config passes.
    #[test]
    fn a_peak_learning_rate_outside_0_1_is_refused() {
        for lr in [0.0, -1e-3, 1.0, 2.0] {
            let mut c = config(100, None);
            c.lr = lr;
            c.lr_final = 0.0;
            let e = c.validate("eventgen").unwrap_err();
            assert!(
                e.starts_with("eventgen.lr: ") && e.ends_with("is out of range: allowed (0, 1)"),
                "lr = {lr}: {e}"
            );
        }
        let mut c = config(100, None);
        c.lr_final = 0.0;
        assert!(c.validate("eventgen").is_ok());
    }
}
