//! The experiment config file; every field is checked, errors name the file and field.

use std::path::{Path, PathBuf};

use anyhow::{Result, anyhow, bail};
use serde::Deserialize;

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    Teaser,
    Quality,
    Complexity,
    Absorption,
    Distributions,
    Nee,
    Fallback,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Teaser => "teaser",
            Kind::Quality => "quality",
            Kind::Complexity => "complexity",
            Kind::Absorption => "absorption",
            Kind::Distributions => "distributions",
            Kind::Nee => "nee",
            Kind::Fallback => "fallback",
        }
    }
}

/// Image size, samples and times of one version (full or quick).
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Image width in pixels (every kind but distributions, which renders nothing).
    #[serde(default, deserialize_with = "whole_in::<W_SIZE, _, _>")]
    size: Option<u32>,
    /// Samples per pixel of each render, split over two seeds where noise is measured
    /// (every kind but distributions and nee, which renders for `seconds`).
    #[serde(default, deserialize_with = "whole_in::<W_SPP, _, _>")]
    spp: Option<u32>,
    /// Equal-time budget in seconds (nee).
    pub seconds: Option<f64>,
    /// Samples per pixel of the converged reference (nee).
    #[serde(default, deserialize_with = "whole_in::<W_REFERENCE_SPP, _, _>")]
    pub reference_spp: Option<u32>,
    /// Samples per eval setting (distributions).
    #[serde(default, deserialize_with = "whole_in::<W_SAMPLES, _, _>")]
    pub samples: Option<usize>,
}

/// The budgets' whole-number fields' ranges (inclusive), which `validate` checks and
/// whose messages say why. Size: `bench render --size`'s, since the figures are measured
/// over 4×4-pixel blocks and the object's pixels; spp: from two seeds, at most bench
/// render's 2^30, whose pairs' halves add up in u32.
const WHOLE: [(u64, u64); 4] = [
    (
        crate::bench_render::MIN_BENCH_SIZE as u64,
        crate::bench_render::MAX_BENCH_SIZE as u64,
    ),
    (2, crate::bench_render::MAX_BENCH_SPP as u64),
    (1, u32::MAX as u64),
    (2, crate::model_cmds::MAX_EVAL_SAMPLES as u64),
];
const W_SIZE: usize = 0;
const W_SPP: usize = 1;
const W_REFERENCE_SPP: usize = 2;
const W_SAMPLES: usize = 3;

/// A list that, where the key is given, holds something: `densities = []` in a fallback
/// config read as no key at all, and the run rendered at the default density under a
/// description of another.
fn non_empty<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Vec<f64>, D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    if v.is_empty() {
        return Err(serde::de::Error::custom(
            "an empty list: give at least one value, or leave the key out",
        ));
    }
    Ok(v)
}

/// Reads one of the budgets' whole numbers (`I` indexes [`WHOLE`]): a value the type
/// cannot hold (negative, fractional, beyond 2^32) is refused with the field's own range
/// (`size = -5` said "expected a whole number in [0, 4294967295]" for a field of
/// [8, 4096]); one the type holds but out of range is left to `validate`, which says why
/// the range is what it is.
fn whole_in<'de, const I: usize, D, T>(d: D) -> std::result::Result<Option<T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: TryFrom<u64>,
{
    let (lo, hi) = WHOLE[I];
    scatter_sim::ranges::whole_in(d, lo, hi).map(Some)
}

impl Budget {
    /// The image width (checked present by `validate` for the kinds that render).
    pub fn size(&self) -> u32 {
        self.size.unwrap_or(0)
    }

    /// The samples per pixel (checked present by `validate` for the kinds that read them).
    pub fn spp(&self) -> u32 {
        self.spp.unwrap_or(0)
    }

    /// The nee kind's time per method (checked present by `validate` for nee, the one kind
    /// that reads it).
    pub fn seconds(&self) -> f64 {
        self.seconds.unwrap_or(0.0)
    }

    /// The nee kind's reference spp (checked present by `validate` for nee, the one kind
    /// that reads it).
    pub fn reference_spp(&self) -> u32 {
        self.reference_spp.unwrap_or(0)
    }

    /// The distributions kind's samples per setting, 10,000 unless given.
    pub fn samples(&self) -> usize {
        self.samples.unwrap_or(10_000)
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub kind: Kind,
    pub title: String,
    #[serde(default)]
    pub description: String,
    /// Scene the experiment varies (relative to the config file).
    pub scene: Option<PathBuf>,
    /// More scenes (complexity: the thin-featured object), relative to the config file.
    #[serde(default)]
    pub scenes: Vec<PathBuf>,
    /// Multipliers of the scene's σ_t.
    #[serde(default, deserialize_with = "non_empty")]
    pub densities: Vec<f64>,
    /// Absorption 1 − φ values (absorption).
    #[serde(default)]
    pub absorptions: Vec<f64>,
    /// Thin-region thresholds min_tau (fallback).
    #[serde(default)]
    pub thresholds: Vec<f64>,
    /// The paper's figures to print beside ours (teaser, quality: speed-ups per density).
    #[serde(default)]
    pub paper: Vec<f64>,
    /// Next-event estimation in both integrators (teaser, complexity, absorption,
    /// fallback; default on). Off, only paths escaping into a light's disk or the
    /// environment count, as in the paper's Figs. 6–7 (which leave in-scattered direct
    /// light out, and most likely its other speed-ups): PT then casts no shadow ray at
    /// each event, and the speed-ups are those of the walks alone.
    pub nee: Option<bool>,
    pub full: Budget,
    pub quick: Budget,
    #[serde(skip)]
    pub dir: PathBuf,
}

impl Config {
    pub fn load(path: &Path) -> Result<Self> {
        let text = scatter_sim::output::read_input_to_string(path)
            .map_err(|e| anyhow!("{}: cannot read: {e}", path.display()))?;
        // A scene or another command's config given by mistake reads as "unknown field
        // camera" otherwise: say what the file is.
        crate::generate::wrong_kind(path, &text, render_gpu::scene::ConfigKind::Experiment)?;
        if let Ok(t) = text.parse::<toml::Table>()
            && !t.contains_key("kind")
        {
            bail!(
                "{}: not an experiment config (it has no `kind`): `experiment` takes an \
                 experiment config such as configs/experiments/teaser.toml",
                path.display()
            );
        }
        let mut c: Config = crate::generate::parse_toml(path, &text)?;
        c.dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        c.validate()
            .map_err(|e| anyhow!("{}: {e}", path.display()))?;
        Ok(c)
    }

    fn validate(&self) -> Result<()> {
        for (name, b) in [("full", &self.full), ("quick", &self.quick)] {
            self.check_budget(name, b)?;
        }
        self.check_lists()?;
        self.check_needs()?;
        self.check_fields_read()
    }

    /// One budget (`[full]` or `[quick]`): size and spp given exactly where the kind reads
    /// them, and every field given in its range.
    fn check_budget(&self, name: &str, b: &Budget) -> Result<()> {
        // Which budget fields the kind reads: a size for any kind that renders, spp for
        // those that render a fixed number of samples (nee renders for `seconds`). One the
        // kind does not read would be ignored without a word: refused.
        let renders = self.kind != Kind::Distributions;
        let reads_spp = renders && self.kind != Kind::Nee;
        for (field, given, read) in [
            ("size", b.size.is_some(), renders),
            ("spp", b.spp.is_some(), reads_spp),
        ] {
            if read && !given {
                bail!(
                    "[{name}] needs {field}: kind = \"{}\" renders with it",
                    self.kind.name()
                );
            }
            if given && !read {
                bail!(
                    "{name}.{field} does not apply to kind = \"{}\", which {}: remove it",
                    self.kind.name(),
                    if renders {
                        "renders for `seconds`"
                    } else {
                        "renders no image"
                    }
                );
            }
        }
        // As `bench render --size`: the figures are measured over 4×4-pixel blocks and
        // the object's pixels, which a smaller image hardly has (size 1 reported a
        // variance ratio of 7e297).
        let (lo, hi) = WHOLE[W_SIZE];
        if let Some(size) = b.size
            && !(lo..=hi).contains(&size.into())
        {
            bail!(
                "{name}.size = {size} is out of range: allowed [{lo}, {hi}] (the figures \
                 are measured over 4×4-pixel blocks)"
            );
        }
        // At most bench render's 2^30: a pair's two halves add up in u32.
        let (lo, most) = WHOLE[W_SPP];
        if let Some(spp) = b.spp
            && !(lo..=most).contains(&spp.into())
        {
            bail!(
                "{name}.spp = {spp} is out of range: allowed [{lo}, {most}] (noise is \
                 measured from two seeds)"
            );
        }
        if let Some(s) = b.seconds
            && !(s > 0.0 && s <= 86_400.0)
        {
            bail!(
                "{name}.seconds = {} is out of range: allowed (0, 86400]",
                scatter_sim::ranges::num(s)
            );
        }
        let (lo, hi) = WHOLE[W_SAMPLES];
        if let Some(n) = b.samples
            && !(lo..=hi).contains(&(n as u64))
        {
            bail!("{name}.samples = {n} is out of range: allowed [{lo}, {hi}]");
        }
        let (lo, hi) = WHOLE[W_REFERENCE_SPP];
        if let Some(n) = b.reference_spp
            && u64::from(n) < lo
        {
            bail!(
                "{name}.reference_spp = {n} is out of range: allowed {}",
                scatter_sim::ranges::whole_range(lo, hi)
            );
        }
        Ok(())
    }

    /// The lists of densities, paper figures, absorptions and thresholds, each value in its
    /// range.
    fn check_lists(&self) -> Result<()> {
        let positive = |what: &str, v: &[f64]| -> Result<()> {
            if let Some(x) = v.iter().find(|x| !(**x > 0.0) || !x.is_finite()) {
                bail!("{what} must be positive and finite (found {x})");
            }
            Ok(())
        };
        // The range `bench render --k` takes (bench_render::parse_k): a density of 1e-300
        // rendered an empty object and printed 300-digit figures.
        if let Some(k) = self
            .densities
            .iter()
            .find(|k| !(0.001..=1000.0).contains(*k))
        {
            bail!(
                "densities: {} is out of range: allowed [0.001, 1000] (multipliers of the \
                 scene's sigma_t)",
                scatter_sim::ranges::num(*k)
            );
        }
        positive("paper", &self.paper)?;
        positive("absorptions", &self.absorptions)?;
        if self.absorptions.iter().any(|&a| a >= 1.0) {
            bail!("absorptions are 1 − φ and must be below 1");
        }
        // As densities: 1e-300 printed a 300-digit figure. Below ~1e-6 the renderer's f32
        // albedo 1 − a misstates a by more than 1 % (f32 steps by 6e-8 below 1), and below
        // ~3e-8 it is 1 (no absorption at all).
        if let Some(a) = self.absorptions.iter().find(|a| **a < 1e-6) {
            bail!(
                "absorptions: {} is out of range: allowed [1e-6, 1) (1 − φ; below 1e-6 the \
                 renderer's single-precision albedo misstates it by more than 1 %)",
                scatter_sim::ranges::num(*a)
            );
        }
        let most = render_gpu::scene::MAX_SCENE_VALUE;
        if let Some(t) = self.thresholds.iter().find(|t| !(0.0..=most).contains(*t)) {
            bail!(
                "thresholds: {} is out of range: allowed [0, {most:e}] (min_tau, as in a scene)",
                scatter_sim::ranges::num(*t)
            );
        }
        Ok(())
    }

    /// What the kind needs: a scene (not named ""), its list, its budgets' fields; and at
    /// most one `paper` figure per density.
    fn check_needs(&self) -> Result<()> {
        let needs_scene = self.kind != Kind::Distributions;
        if needs_scene && self.scene.is_none() {
            bail!("scene is required for kind = \"{}\"", self.kind.name());
        }
        // Joined to the config's folder, "" read as that folder ("cannot read scene file:
        // Is a directory").
        if self
            .scene
            .as_ref()
            .is_some_and(|p| p.as_os_str().is_empty())
        {
            bail!("scene = \"\" names no file: give a scene file");
        }
        if self.scenes.iter().any(|p| p.as_os_str().is_empty()) {
            bail!("scenes holds \"\", which names no file: give scene files");
        }
        let needs = |ok: bool, what: &str| -> Result<()> {
            if !ok {
                bail!("kind = \"{}\" needs {what}", self.kind.name());
            }
            Ok(())
        };
        match self.kind {
            Kind::Teaser | Kind::Quality | Kind::Complexity => {
                needs(!self.densities.is_empty(), "densities")?
            }
            Kind::Absorption => needs(!self.absorptions.is_empty(), "absorptions")?,
            Kind::Fallback => {
                needs(!self.thresholds.is_empty(), "thresholds")?;
                // It varies min_tau at one density (the first was used, the rest ignored).
                if self.densities.len() > 1 {
                    bail!(
                        "kind = \"fallback\" takes at most one density (the default is 1), \
                         found {}",
                        self.densities.len()
                    );
                }
            }
            Kind::Nee => needs(
                self.full.seconds.is_some()
                    && self.quick.seconds.is_some()
                    && self.full.reference_spp.is_some()
                    && self.quick.reference_spp.is_some(),
                "full/quick seconds and reference_spp",
            )?,
            Kind::Distributions => {}
        }
        // After the kind's own needs: an empty list is reported as missing, not as a
        // mismatch with `paper`.
        if self.paper.len() > self.densities.len() {
            bail!(
                "paper lists {} figures for {} densit{}: one per density at most",
                self.paper.len(),
                self.densities.len(),
                if self.densities.len() == 1 {
                    "y"
                } else {
                    "ies"
                }
            );
        }
        Ok(())
    }

    /// A field the kind does not read is refused.
    fn check_fields_read(&self) -> Result<()> {
        // A field the kind does not read would be ignored without a word (thresholds in a
        // teaser, seconds under [quick] of a quality run): refused, naming what it reads.
        let reads: &[&str] = match self.kind {
            Kind::Teaser => &["scene", "densities", "paper", "nee"],
            Kind::Quality => &["scene", "densities", "paper"],
            Kind::Complexity => &["scene", "scenes", "densities", "nee"],
            Kind::Absorption => &["scene", "absorptions", "nee"],
            Kind::Distributions => &["samples"],
            Kind::Nee => &["scene", "seconds", "reference_spp"],
            Kind::Fallback => &["scene", "densities", "thresholds", "nee"],
        };
        let budgets = [&self.full, &self.quick];
        let given = [
            ("scene", self.scene.is_some()),
            ("scenes", !self.scenes.is_empty()),
            ("densities", !self.densities.is_empty()),
            ("absorptions", !self.absorptions.is_empty()),
            ("thresholds", !self.thresholds.is_empty()),
            ("paper", !self.paper.is_empty()),
            ("nee", self.nee.is_some()),
            ("seconds", budgets.iter().any(|b| b.seconds.is_some())),
            (
                "reference_spp",
                budgets.iter().any(|b| b.reference_spp.is_some()),
            ),
            ("samples", budgets.iter().any(|b| b.samples.is_some())),
        ];
        if let Some((field, _)) = given.iter().find(|(f, set)| *set && !reads.contains(f)) {
            bail!(
                "{field} does not apply to kind = \"{}\", which reads {} (besides title, \
                 description and the [full]/[quick] budgets): remove it",
                self.kind.name(),
                reads.join(", ")
            );
        }
        Ok(())
    }

    /// Whether the renders use next-event estimation (`nee`, default on).
    pub fn nee(&self) -> bool {
        self.nee.unwrap_or(true)
    }

    /// Whether some render of this experiment counts light only where a path escapes
    /// into it: `nee = false`, or the nee kind's PT row without NEE.
    pub fn renders_without_nee(&self) -> bool {
        !self.nee() || self.kind == Kind::Nee
    }

    pub fn scene_path(&self) -> PathBuf {
        self.dir
            .join(self.scene.as_deref().unwrap_or(Path::new("")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `text` parsed and validated as `Config::load` does (without a file), its error as
    /// text.
    fn check(text: &str) -> std::result::Result<(), String> {
        let c: Config = toml::from_str(text).map_err(|e| e.to_string())?;
        c.validate().map_err(|e| e.to_string())
    }

    /// A nee config whose [full] and [quick] hold `full` and `quick` beside the size.
    fn nee(full: &str, quick: &str) -> String {
        format!(
            "kind = \"nee\"\ntitle = \"t\"\nscene = \"s.toml\"\n[full]\nsize = 8\n{full}\n\
             [quick]\nsize = 8\n{quick}\n"
        )
    }

    const BOTH: &str = "seconds = 1.0\nreference_spp = 4";

    /// Each of the four budget fields of the nee kind, left out in turn, is refused (a
    /// missing reference_spp read as 0 spp, a missing seconds as 0 s).
    #[test]
    fn nee_needs_seconds_and_reference_spp_in_both_budgets() {
        check(&nee(BOTH, BOTH)).unwrap();
        for (full, quick) in [
            ("seconds = 1.0", BOTH),
            ("reference_spp = 4", BOTH),
            (BOTH, "seconds = 1.0"),
            (BOTH, "reference_spp = 4"),
        ] {
            let e = check(&nee(full, quick)).unwrap_err();
            assert!(
                e.contains("kind = \"nee\" needs full/quick seconds and reference_spp"),
                "{full} / {quick}: {e}"
            );
        }
    }

    /// The equal-time budget lies in (0, 86400] s: 0 is refused, a millisecond is not.
    #[test]
    fn nee_seconds_must_be_above_zero() {
        check(&nee("seconds = 0.001\nreference_spp = 4", BOTH)).unwrap();
        let e = check(&nee("seconds = 0.0\nreference_spp = 4", BOTH)).unwrap_err();
        assert!(
            e.contains("full.seconds = 0 is out of range: allowed (0, 86400]"),
            "{e}"
        );
    }

    /// Absorptions are 1 − φ and lie below 1: exactly 1 (an albedo of 0) is refused.
    #[test]
    fn an_absorption_of_one_is_refused() {
        let absorption = |list: &str| {
            format!(
                "kind = \"absorption\"\ntitle = \"t\"\nscene = \"s.toml\"\n\
                 absorptions = [{list}]\n[full]\nsize = 8\nspp = 2\n[quick]\nsize = 8\nspp = 2\n"
            )
        };
        check(&absorption("0.5, 0.999")).unwrap();
        let e = check(&absorption("0.5, 1.0")).unwrap_err();
        assert!(
            e.contains("absorptions are 1 − φ and must be below 1"),
            "{e}"
        );
    }
}
