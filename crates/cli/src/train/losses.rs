//! What the losses say of a trained model: a loss that rose (refused unless asked), a
//! held-out loss far above the training walks' (warned of), and the loss curves' plot.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use cvae::train::ModelKind;
use cvae::train::validation::ValidationPoint;

use super::{Args, resume_command};

/// The untrained loss when a run's last reported loss is above it by more than a tenth
/// (of it, or of 1 near 0): the first report is one step's batch, so a margin keeps its
/// noise from refusing a model that did learn. Losses may be negative (the
/// log-variance heads).
pub(super) fn loss_rose(history: &[(u64, f32)]) -> Option<f32> {
    let (&(_, first), &(_, last)) = (history.first()?, history.last()?);
    (last > first + 0.1 * first.abs().max(1.0)).then_some(first)
}

/// "K's from FIRST (untrained) to LAST" where `k`'s loss rose ([`loss_rose`]): how the
/// refusals of a diverged model name it, trained now or taken from its checkpoint.
pub(super) fn loss_rise(k: ModelKind, history: &[(u64, f32)]) -> Option<String> {
    let first = loss_rose(history)?;
    let last = history.last()?.1;
    Some(format!(
        "{}'s from {first:.4} (untrained) to {last:.4}",
        k.name()
    ))
}

/// Held-out losses this far above the training walks' (`ValidationPoint::gap_z`, N(0, 1)
/// while the model generalises) are reported as memorising: noise alone passes it with
/// probability ~3·10⁻⁵ at 2,048 rows a side (~1.5·10⁻⁴ at the fewest, 20, where z follows
/// Student's t with ~38 degrees of freedom).
const GAP_WARNING_Z: f32 = 4.0;

/// Where the loss curves of model file `out` go: NAME.loss.png for NAME.stcvae, else the
/// whole file name with .loss.png added (`with_extension` gave m.v1 and m.v2 one plot).
pub(super) fn loss_plot_path(out: &Path) -> PathBuf {
    let mut name = match out.extension() {
        Some(e) if e == "stcvae" => out.with_extension(""),
        _ => out.to_path_buf(),
    }
    .into_os_string();
    name.push(".loss.png");
    PathBuf::from(name)
}

/// The trained models' validation losses against their steps, as the PNG for
/// [`loss_plot_path`]; `None` when no model read any.
pub(super) fn loss_plot(path: &Path, trained: &[cvae::train::Trained]) -> Result<Option<Vec<u8>>> {
    use crate::plots::{Series, line_plot_png};
    let mut series = Vec::new();
    // One colour per model, the same in every run whatever order the models finished in:
    // its training walks solid, its held-out walks dashed.
    for (i, kind) in ModelKind::ALL.into_iter().enumerate() {
        let Some(t) = trained
            .iter()
            .find(|t| t.kind == kind && !t.info.validation.is_empty())
        else {
            continue;
        };
        let points = |f: fn(&ValidationPoint) -> f32| {
            t.info
                .validation
                .iter()
                .map(|v| (v.step as f64, f64::from(f(v))))
                .collect()
        };
        series.push(Series {
            colour: Some(i),
            ..Series::new(
                format!("{} training walks", t.kind.name()),
                points(|v| v.train.0),
            )
        });
        series.push(Series {
            colour: Some(i),
            dashed: true,
            ..Series::new(
                format!("{} held-out walks", t.kind.name()),
                points(|v| v.held_out.0),
            )
        });
    }
    if series.is_empty() {
        return Ok(None);
    }
    line_plot_png(
        path,
        "Validation loss (negative ELBO, fixed draws)",
        "step",
        "loss",
        (true, false),
        &series,
    )
    .map(Some)
}

/// The warnings a trained model calls for (a step count past the one asked, a model that
/// learned its walks rather than their distribution), printed, and the model file's note
/// on it (`resumed`: its seconds span several runs).
pub(super) fn trained_note(t: &cvae::train::Trained, steps: u64, resumed: bool) -> String {
    if t.info.step > steps {
        eprintln!(
            "note: {}'s checkpoint was already at step {}, past the {steps} steps asked: \
             exported as it was (no step undone)",
            t.kind.name(),
            t.info.step
        );
    }
    let last = t.info.history.last().map_or(f32::NAN, |h| h.1);
    let held = t.info.validation.last();
    if let Some(v) = held
        && v.gap_z > GAP_WARNING_Z
    {
        eprintln!(
            "warning: {}'s losses on held-out walks (mean {:.4}) lie above those on its \
             training walks (mean {:.4}) by z = {:.0}: it is learning the dataset's walks \
             rather than their distribution; train on more walks (a larger `walks` in the \
             dataset config) or for fewer steps",
            t.kind.name(),
            v.held_out.0,
            v.train.0,
            v.gap_z
        );
    }
    // A resumed model's seconds include the runs before this one (one that --resume
    // found no checkpoint of started this run).
    format!(
        "{}: {}, final loss {last:.4}{}, {:.0} s{}",
        t.kind.name(),
        crate::progress::count(t.info.step, "step"),
        held.map_or(String::new(), |v| format!(
            " (held-out {:.4})",
            v.held_out.0
        )),
        t.info.seconds,
        if resumed { " over all its runs" } else { "" }
    )
}

/// A learning rate too high can leave a finite but useless model, its loss above the
/// untrained network's (one run's EventGen went from 6.07 to 21,916). Written with a
/// warning and exit status 0, such a file went on into `train && render` scripts; it is
/// now written only when `--keep-diverged` asks. The checkpoints are kept either way, so
/// the file can still be had without training again.
pub(super) fn refuse_diverged(a: &Args, trained: &[cvae::train::Trained]) -> Result<()> {
    let rose: Vec<String> = trained
        .iter()
        .filter_map(|t| loss_rise(t.kind, &t.info.history))
        .collect();
    if rose.is_empty() {
        return Ok(());
    }
    if a.keep_diverged {
        eprintln!(
            "warning: the loss rose ({}): the model diverged or learned nothing; written \
             as --keep-diverged asks",
            rose.join(", ")
        );
        return Ok(());
    }
    bail!(
        "the loss rose ({}): training diverged or learned nothing, so no model was written; \
         lower lr or lr_final in {} (or check the dataset) and train again with --fresh, or \
         write this one as it is with `{} --keep-diverged`",
        rose.join(", "),
        a.config.display(),
        resume_command(a)
    )
}
