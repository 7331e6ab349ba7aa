//! The training config (TOML): its fields, defaults and checks.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use cvae::model_file::SingleScattering;
use cvae::train::{ModelConfig, ModelKind};
use serde::Deserialize;

use crate::generate::parse_toml;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TrainConfig {
    pub(super) dataset: PathBuf,
    /// Dataset config used to generate `dataset` when it does not exist.
    pub(super) dataset_config: Option<PathBuf>,
    pub(super) out: PathBuf,
    pub(super) checkpoint_dir: PathBuf,
    #[serde(default = "one")]
    pub(super) seed: u64,
    #[serde(default = "exact")]
    pub(super) single_scattering: SingleScattering,
    #[serde(
        default = "checkpoint_every",
        deserialize_with = "crate::generate::at_least_one"
    )]
    pub(super) checkpoint_every: u64,
    lengthgen: ModelConfig,
    pathgen: ModelConfig,
    eventgen: ModelConfig,
}

fn one() -> u64 {
    1
}

fn exact() -> SingleScattering {
    SingleScattering::Exact
}

fn checkpoint_every() -> u64 {
    5000
}

impl TrainConfig {
    pub(super) fn model(&self, k: ModelKind) -> &ModelConfig {
        match k {
            ModelKind::LengthGen => &self.lengthgen,
            ModelKind::PathGen => &self.pathgen,
            ModelKind::EventGen => &self.eventgen,
        }
    }
}

/// The shipped training config, relative to the repository root.
pub(super) const DEFAULT_CONFIG: &str = "configs/train/default.toml";

/// Paths in a config are relative to the current directory (the repository root for
/// the shipped configs), like every other path on the command line.
pub(super) fn load(path: &Path) -> Result<TrainConfig> {
    let text = scatter_sim::output::read_input_to_string(path).with_context(|| {
        // The default's paths inside (dataset, dataset_config, checkpoints, out) are
        // relative to the repository root too, so it is not looked for elsewhere.
        let hint = if path == Path::new(DEFAULT_CONFIG) && !path.exists() {
            " (run from the repository root, where the shipped configs are, or pass --config)"
        } else {
            ""
        };
        format!("cannot read training config {}{hint}", path.display())
    })?;
    crate::generate::wrong_kind(path, &text, render_gpu::scene::ConfigKind::Training)?;
    let cfg: TrainConfig = parse_toml(path, &text)?;
    // An empty path is the current directory (nine checkpoint files landed there) or no
    // file at all ("error: : No such file or directory" after the dataset was made).
    let paths = [
        ("dataset", Some(&cfg.dataset)),
        ("dataset_config", cfg.dataset_config.as_ref()),
        ("out", Some(&cfg.out)),
        ("checkpoint_dir", Some(&cfg.checkpoint_dir)),
    ];
    if let Some((field, _)) = paths
        .iter()
        .find(|(_, p)| p.is_some_and(|p| p.as_os_str().is_empty()))
    {
        bail!("{}: {field} = \"\" names no path", path.display());
    }
    // A CSV was generated in full (2^22 walks with the shipped config) and then refused as
    // "not an stcvae dataset (bad magic bytes)".
    if scatter_sim::dataset::is_csv(&cfg.dataset) {
        bail!(
            "{}: dataset = \"{}\": train reads binary datasets (e.g. .bin; `stcvae generate` \
             writes one for any other name than .csv)",
            path.display(),
            cfg.dataset.display()
        );
    }
    // 0 turned the periodic checkpoints off without a word: a kill (not a Ctrl-C, which
    // saves one) after most of an hour lost the whole run.
    if cfg.checkpoint_every == 0 {
        bail!(
            "{}: checkpoint_every = 0 is out of range: allowed {} (steps between checkpoints)",
            path.display(),
            scatter_sim::ranges::whole_range(1, u64::MAX)
        );
    }
    for k in ModelKind::ALL {
        cfg.model(k)
            .validate(k.name())
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    Ok(cfg)
}
