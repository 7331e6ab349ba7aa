//! End-to-end checks of `stcvae train`: one model retrained against an existing model
//! file (`--model K --base M`) keeps the other two decoders bit for bit; resumed, fresh,
//! diverged and memorising runs; edited and damaged checkpoints.

mod common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use common::{stcvae, stderr, words};
use cvae::model_file::ModelSet;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `stcvae train --config train.toml --model eventgen --base BASE` in `dir`.
fn train_eventgen(dir: &Path, base: &str) -> Output {
    train_one(dir, "eventgen", base)
}

/// `stcvae train --config train.toml --model MODEL --base BASE` in `dir`.
fn train_one(dir: &Path, model: &str, base: &str) -> Output {
    stcvae(
        &[
            "train",
            "--config",
            "train.toml",
            "--model",
            model,
            "--base",
            base,
        ],
        dir,
    )
}

/// `file` with `from` replaced by `to`, which it must hold (a setup that no longer matches
/// would otherwise test the unchanged config).
fn replace_in(file: &Path, from: &str, to: &str) {
    let text = fs::read_to_string(file).unwrap();
    assert!(text.contains(from), "{} holds no {from}", file.display());
    fs::write(file, text.replace(from, to)).unwrap();
}

/// A tiny dataset and a config whose EventGen is deliberately unlike the shipped one
/// (hidden [4, 4]), so the output's EventGen can only have come from this run.
fn setup(dir: &Path) {
    let data = "walks = 3001\nseed = 5\n[conditions]\n\
                tau = { kind = \"power\", max = 30.0, exponent = 3.0 }\n\
                g = { kind = \"uniform\", min = -1.0, max = 1.0 }\n\
                albedo = { kind = \"one-minus-power\", epsilon = 1e-6, exponent = 6.0 }\n";
    fs::write(dir.join("data.toml"), data).unwrap();
    let model = |hidden: &str| {
        format!(
            "latent = 2\nhidden = {hidden}\nencoder_hidden = [8]\nsteps = 30\n\
             batch_size = 64\nlr = 3e-3\nlr_final = 3e-4\nwarmup = 5\n"
        )
    };
    let cfg = format!(
        "dataset = \"d.bin\"\ndataset_config = \"data.toml\"\nout = \"m.stcvae\"\n\
         checkpoint_dir = \"ck\"\n[lengthgen]\n{}[pathgen]\n{}[eventgen]\n{}",
        model("[4]"),
        model("[4]"),
        model("[4, 4]")
    );
    fs::write(dir.join("train.toml"), cfg).unwrap();
}

/// [`setup`], then one full training run of the config, which must succeed: the
/// checkpoints the tests of resume, --fresh and stopping start from.
fn setup_and_train(dir: &Path) {
    setup(dir);
    let o = stcvae(&["train", "--config", "train.toml"], dir);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn one_model_retrained_against_a_base_file_keeps_the_others() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let base = root().join("models/default.stcvae");
    let base_s = base.to_str().unwrap();
    let out = train_eventgen(dir.path(), base_s);
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    assert!(!stderr(&out).contains("every walk has"), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("render with it: stcvae render --model m.stcvae"),
        "{}",
        stderr(&out)
    );
    let shipped = ModelSet::load(&base).unwrap();
    let got = ModelSet::load(&dir.path().join("m.stcvae")).unwrap();
    assert_eq!(
        got.length, shipped.length,
        "LengthGen must come from --base"
    );
    assert_eq!(got.path, shipped.path, "PathGen must come from --base");
    assert_ne!(
        got.event, shipped.event,
        "EventGen must be the one just trained"
    );
    // [4, 4] hidden: two hidden layers of width 4 ahead of the mean/log-variance head.
    assert_eq!(got.event.layers.len(), 3);
    // A file's feature version says how its EventGen is read: this build's, for the
    // EventGen just trained, whatever the base's.
    assert_eq!(got.feature_version, cvae::features::FEATURE_VERSION);
    // Retraining another model keeps the base's EventGen, and with it the base's version:
    // here a version-2 copy of the file just written (the same decoders read the old way).
    let mut old = got.clone();
    old.feature_version = cvae::features::OLDEST_FEATURE_VERSION;
    old.save(&dir.path().join("old.stcvae")).unwrap();
    let out = train_one(dir.path(), "pathgen", "old.stcvae");
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    let mixed = ModelSet::load(&dir.path().join("m.stcvae")).unwrap();
    assert_eq!(mixed.event, old.event);
    assert_eq!(
        mixed.feature_version,
        cvae::features::OLDEST_FEATURE_VERSION
    );
    assert!(
        got.training
            .notes
            .contains(&format!("lengthgen: from {base_s}")),
        "{}",
        got.training.notes
    );
    // Ranges: only what both trainings saw (this dataset's τ ≤ 30, the base's up to 300).
    assert!(
        got.training.tau_range[1] <= 30.0,
        "{:?}",
        got.training.tau_range
    );
    assert!(got.training.tau_range[0] >= shipped.training.tau_range[0]);
}

/// A dataset that is there is trained on as it is; one that is not the run its
/// dataset_config describes (the config edited since) says so.
#[test]
fn a_dataset_not_of_its_config_is_named() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let base = root().join("models/default.stcvae");
    let base = base.to_str().unwrap();
    let out = train_one(dir.path(), "lengthgen", base);
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    assert!(!stderr(&out).contains("is not the run"), "{}", stderr(&out));
    let retrain = || {
        let args = [
            "train",
            "--config",
            "train.toml",
            "--model",
            "lengthgen",
            "--base",
        ];
        let out = stcvae(&[&args[..], &[base, "--fresh"]].concat(), dir.path());
        assert!(out.status.success(), "train failed: {}", stderr(&out));
        out
    };
    // Drawn by another simulator (its fingerprint changed, rows kept): said so.
    let d = dir.path().join("d.bin");
    common::rewrite_dataset(&d, &d, |h| h.pieces[0].simulator = Some("0badc0de".into()));
    let out = retrain();
    assert!(
        stderr(&out).contains(&format!(
            "warning: d.bin was generated by another simulator (fingerprint 0badc0de; this \
             build's is {}",
            scatter_sim::dataset::simulator_fingerprint()
        )) && !stderr(&out).contains("is not the run"),
        "{}",
        stderr(&out)
    );
    replace_in(&dir.path().join("data.toml"), "seed = 5", "seed = 6");
    let out = retrain();
    assert!(
        stderr(&out).contains(
            "warning: d.bin is not the run data.toml describes (seed 6, 3001 walks): it holds \
             3001 walks of a run with seed 5, 3001 walks, the config's conditions. Training on \
             it as it is"
        ),
        "{}",
        stderr(&out)
    );
}

/// The shipped training config must not write over the shipped model: `train` writes
/// feature version 3 and the shipped file is version 2, validated for its image.
#[test]
fn the_shipped_config_leaves_the_shipped_model_alone() {
    let cfg: toml::Value =
        toml::from_str(&fs::read_to_string(root().join("configs/train/default.toml")).unwrap())
            .unwrap();
    let out = cfg["out"].as_str().unwrap();
    assert_ne!(Path::new(out), Path::new("models/default.stcvae"));
    assert!(out.starts_with("models/"), "{out}");
    let ignore = fs::read_to_string(root().join(".gitignore")).unwrap();
    assert!(
        ignore.lines().any(|l| l == format!("/{out}")),
        "{out} should be ignored by git, like every other output"
    );
}

/// A dataset whose walks all share one g trains, with a warning that the model knows only
/// that g; and a checkpoint_dir that cannot be created fails before the dataset is even
/// generated, naming the config and the field.
#[test]
fn a_fixed_condition_warns_and_a_bad_checkpoint_dir_fails_first() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    replace_in(
        &dir.path().join("data.toml"),
        "g = { kind = \"uniform\", min = -1.0, max = 1.0 }",
        "g = { kind = \"fixed\", value = 0.25 }",
    );
    let base = root().join("models/default.stcvae");
    let out = train_eventgen(dir.path(), base.to_str().unwrap());
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    assert!(
        stderr(&out).contains("every walk has g = 0.25; the model will know only that value"),
        "{}",
        stderr(&out)
    );
    // Its evaluation on the paper's grid says the grid's g lie outside what it knows (the
    // figures were reported as a fit), on the terminal and in metrics.md.
    let out = stcvae(
        &[
            "eval",
            "--model",
            "m.stcvae",
            "--samples",
            "50",
            "--out",
            "ev",
        ],
        dir.path(),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let want = "g -0.7, 0, 0.4, 0.9 (trained [0.25, 0.25]) lie outside the model's training range";
    assert!(stderr(&out).contains(want), "{}", stderr(&out));
    let md = fs::read_to_string(dir.path().join("ev/metrics.md")).unwrap();
    assert!(md.contains(want), "{md}");
    // `eval --at` the same, each setting's warning in its metrics.md too (it went to the
    // terminal only).
    let out = stcvae(
        &words("eval --model m.stcvae --at 5,0.5,1 --samples 50 --out ev2"),
        dir.path(),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let want = "--at g 0.5 lies outside the model's training range [0.25, 0.25]";
    assert!(stderr(&out).contains(want), "{}", stderr(&out));
    let md = fs::read_to_string(dir.path().join("ev2/metrics.md")).unwrap();
    assert!(md.contains(want), "{md}");
    // So does an experiment rendering with it (the bunny's g = 0.875), in its report too.
    // `stcvae experiment configs/experiments/NAME.toml --quick` with this model, which
    // must succeed.
    let experiment = |name: &str| {
        let cfg = root().join(format!("configs/experiments/{name}.toml"));
        let out = stcvae(
            &[
                "experiment",
                cfg.to_str().unwrap(),
                "--quick",
                "--device",
                "cpu",
                "--model",
                "m.stcvae",
                "--out",
                "res",
            ],
            dir.path(),
        );
        assert!(out.status.success(), "{}", stderr(&out));
        out
    };
    let out = experiment("teaser");
    let want = "medium.g = 0.875 (trained [0.25, 0.25]) outside the model's training range";
    assert_eq!(stderr(&out).matches(want).count(), 1, "{}", stderr(&out));
    let report = fs::read_to_string(dir.path().join("res/teaser-quick/report.md")).unwrap();
    assert!(report.contains(want), "{report}");
    // And the distributions experiment, whose report embeds the eval's plots (the warning
    // was in its metrics.md only).
    experiment("distributions");
    let want = "g -0.7, 0, 0.4, 0.9 (trained [0.25, 0.25]) lie outside the model's training range";
    let report = fs::read_to_string(dir.path().join("res/distributions-quick/report.md")).unwrap();
    assert!(report.contains(want), "{report}");
    fs::remove_file(dir.path().join("d.bin")).unwrap();
    fs::write(dir.path().join("afile"), b"").unwrap();
    replace_in(
        &dir.path().join("train.toml"),
        "checkpoint_dir = \"ck\"",
        "checkpoint_dir = \"afile/ck\"",
    );
    let out = train_eventgen(dir.path(), base.to_str().unwrap());
    assert!(!out.status.success());
    assert!(
        stderr(&out)
            .contains("train.toml: checkpoint_dir = afile/ck: afile exists and is not a directory"),
        "{}",
        stderr(&out)
    );
    assert!(
        !dir.path().join("d.bin").exists(),
        "the dataset was generated first"
    );
    // A warm-up longer than the run would never reach lr: refused by model and field.
    replace_in(
        &dir.path().join("train.toml"),
        "warmup = 5\n[pathgen]",
        "warmup = 31\n[pathgen]",
    );
    let out = train_eventgen(dir.path(), base.to_str().unwrap());
    assert!(!out.status.success());
    assert!(
        stderr(&out)
            .contains("train.toml: lengthgen.warmup: 31 is out of range: allowed [0, steps = 30]"),
        "{}",
        stderr(&out)
    );
    // An empty path names the field (checkpoint_dir = "" wrote into the working directory),
    // and so do too many hidden layers (the GPU kernels unroll each one).
    replace_in(
        &dir.path().join("train.toml"),
        "warmup = 31\n",
        "warmup = 5\n",
    );
    replace_in(&dir.path().join("train.toml"), "afile/ck", "");
    let out = train_eventgen(dir.path(), base.to_str().unwrap());
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("train.toml: checkpoint_dir = \"\" names no path"),
        "{err}"
    );
    replace_in(
        &dir.path().join("train.toml"),
        "checkpoint_dir = \"\"",
        "checkpoint_dir = \"ck\"",
    );
    replace_in(
        &dir.path().join("train.toml"),
        "hidden = [4, 4]",
        "hidden = [4, 4, 4, 4, 4, 4, 4, 4, 4]",
    );
    let out = train_eventgen(dir.path(), base.to_str().unwrap());
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains(
            "eventgen.hidden: 9 layers, out of range: allowed [1, 8] layers, each of width \
             [1, 64]"
        ),
        "{err}"
    );
}

/// A dataset that is to be generated where it cannot be written is refused naming the
/// config's `dataset` field, before anything is generated: it was blamed on `--out`, a
/// flag of `generate` that the user never gave.
#[test]
fn an_unwritable_dataset_path_names_the_config_field() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    fs::write(dir.path().join("a_file"), "not a folder").unwrap();
    replace_in(
        &dir.path().join("train.toml"),
        "dataset = \"d.bin\"",
        "dataset = \"a_file/d.bin\"",
    );
    let base = root().join("models/default.stcvae");
    let out = train_eventgen(dir.path(), base.to_str().unwrap());
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("train.toml: dataset = \"a_file/d.bin\": "),
        "{err}"
    );
    assert!(
        !err.contains("--out") && !err.contains("generating"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// A whole number the field's type cannot hold (negative, fractional) is refused with the
/// field's own range, the one its validation then checks: `batch_size = -1` said "expected
/// a whole number, at least 0" (serde's usize), where 0 is refused as well.
#[test]
fn negative_whole_numbers_are_refused_with_the_fields_range() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let cfg = fs::read_to_string(dir.path().join("train.toml")).unwrap();
    for (from, to, range) in [
        ("hidden = [4, 4]", "hidden = [4, -1]", "[1, 64]"),
        ("batch_size = 64", "batch_size = -1", "[1, 1048576]"),
        ("latent = 2", "latent = 0.5", "[1, 16]"),
        ("warmup = 5", "warmup = -5", "[0, 2^40]"),
        ("steps = 30", "steps = -30", "[1, 2^40]"),
        ("encoder_hidden = [8]", "encoder_hidden = [-8]", "[1, 1024]"),
        (
            "checkpoint_dir = \"ck\"",
            "checkpoint_dir = \"ck\"\ncheckpoint_every = -1",
            "[1, 2^64)",
        ),
    ] {
        assert!(cfg.contains(from), "{from}");
        fs::write(dir.path().join("train.toml"), cfg.replacen(from, to, 1)).unwrap();
        let out = stcvae(&["train", "--config", "train.toml"], dir.path());
        let err = stderr(&out);
        assert!(!out.status.success(), "{to}");
        assert!(
            err.contains(&format!("expected a whole number in {range}"))
                && err.contains(to.lines().last().unwrap()),
            "{to}: {err}"
        );
    }
    let data = fs::read_to_string(dir.path().join("data.toml")).unwrap();
    fs::write(
        dir.path().join("data.toml"),
        data.replacen("walks = 3001", "walks = -1", 1),
    )
    .unwrap();
    let out = stcvae(
        &["generate", "--config", "data.toml", "--out", "x.bin"],
        dir.path(),
    );
    let err = stderr(&out);
    assert!(
        !out.status.success() && err.contains("data.toml:1:") && err.contains("[1, 2^64)"),
        "{err}"
    );
    assert!(!dir.path().join("x.bin").exists());
}

#[test]
fn a_bad_base_fails_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let out = train_eventgen(dir.path(), "missing.stcvae");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains("missing.stcvae"), "{err}");
    assert!(
        !dir.path().join("d.bin").exists(),
        "the dataset must not be generated before --base is read"
    );
    // The base as the output: refused before it could be overwritten.
    fs::copy(
        root().join("models/default.stcvae"),
        dir.path().join("m.stcvae"),
    )
    .unwrap();
    let out = train_eventgen(dir.path(), "m.stcvae");
    assert!(!out.status.success());
    assert!(stderr(&out).contains("also the output"), "{}", stderr(&out));
    // --base needs --model: with all three trained it would replace nothing.
    let out = stcvae(
        &["train", "--config", "train.toml", "--base", "m0.stcvae"],
        dir.path(),
    );
    assert!(!out.status.success());
    assert!(stderr(&out).contains("--model"), "{}", stderr(&out));
    // One model without --base takes the others from checkpoints: none there is refused
    // before the dataset and the training (it used to fail after them).
    let out = stcvae(
        &["train", "--config", "train.toml", "--model", "pathgen"],
        dir.path(),
    );
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("needs lengthgen") && err.contains("--base"),
        "{err}"
    );
    assert!(
        !dir.path().join("d.bin").exists(),
        "no dataset before the check"
    );
    assert!(
        !dir.path().join("ck").exists(),
        "no checkpoint before the check"
    );
    // One that is there but damaged is named as such: training it "first" is not the
    // advice then.
    fs::create_dir_all(dir.path().join("ck")).unwrap();
    fs::write(dir.path().join("ck/lengthgen.json"), b"{\"step\": ").unwrap();
    let out = stcvae(
        &["train", "--config", "train.toml", "--model", "pathgen"],
        dir.path(),
    );
    let err = stderr(&out);
    assert!(
        !out.status.success()
            && err.contains("needs lengthgen, whose checkpoint in ck cannot be used")
            && err.contains("train --model lengthgen --fresh")
            && !err.contains("train it first"),
        "{err}"
    );
}

/// Outputs that would replace another kind of file or a checkpoint, and a CSV dataset, are
/// refused before any dataset is generated or model trained (a CSV dataset was generated
/// in full and then refused as "bad magic bytes"; `--out ck`, the checkpoints' folder,
/// failed only after training). A model file beside the checkpoints is fine.
#[test]
fn wrong_outputs_and_csv_datasets_fail_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    for (out, want) in [
        (
            "w.csv",
            "--out w.csv: this writes a model file (.stcvae), not a .csv file",
        ),
        ("ck", "--out ck is checkpoint_dir = ck of train.toml"),
        ("ck/lengthgen.bpk", "not a .bpk file"),
        ("ck/lengthgen.json", "not a .json file"),
    ] {
        let o = stcvae(
            &["train", "--config", "train.toml", "--out", out],
            dir.path(),
        );
        assert!(!o.status.success(), "{out}");
        assert!(stderr(&o).contains(want), "{out}: {}", stderr(&o));
    }
    replace_in(&dir.path().join("train.toml"), "d.bin", "d.csv");
    let o = stcvae(&["train", "--config", "train.toml"], dir.path());
    assert!(
        !o.status.success() && stderr(&o).contains("train reads binary datasets"),
        "{}",
        stderr(&o)
    );
    for f in ["d.bin", "d.csv", "ck"] {
        assert!(!dir.path().join(f).exists(), "{f} made before the checks");
    }
    replace_in(&dir.path().join("train.toml"), "d.csv", "d.bin");
    // checkpoint_every = 0 turned the periodic checkpoints off unsaid; a final rate above
    // the peak is named as lr_final (it was reported as lr).
    let cfg = dir.path().join("train.toml");
    let text = fs::read_to_string(&cfg).unwrap();
    for (from, to, want) in [
        (
            "checkpoint_dir = \"ck\"\n",
            "checkpoint_dir = \"ck\"\ncheckpoint_every = 0\n",
            "train.toml: checkpoint_every = 0 is out of range: allowed [1, 2^64)",
        ),
        (
            "lr_final = 3e-4",
            "lr_final = 5e-3",
            "lengthgen.lr_final: 0.005 is out of range: allowed [0, lr = 0.003]",
        ),
    ] {
        replace_in(&cfg, from, to);
        let o = stcvae(&["train", "--config", "train.toml"], dir.path());
        assert!(
            !o.status.success() && stderr(&o).contains(want),
            "{}",
            stderr(&o)
        );
        fs::write(&cfg, &text).unwrap();
    }
    // Steps a config may ask for (2^40), scaled past them: the checkpoints would have been
    // refused as damaged on --resume.
    replace_in(&cfg, "steps = 30\n", "steps = 1099511627776\n");
    let o = stcvae(
        &["train", "--config", "train.toml", "--steps-scale", "2"],
        dir.path(),
    );
    assert!(
        !o.status.success()
            && stderr(&o).contains(
                "--steps-scale 2 gives lengthgen.steps = 2199023255552 in train.toml: \
                 allowed at most 2^40"
            ),
        "{}",
        stderr(&o)
    );
    fs::write(&cfg, &text).unwrap();
    assert!(
        !dir.path().join("d.bin").exists(),
        "the dataset made before the checks"
    );
    // A model file among the checkpoints replaces none of them.
    let o = stcvae(
        &["train", "--config", "train.toml", "--out", "ck/m.stcvae"],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.path().join("ck/m.stcvae").is_file());
    // An existing file that is not a model is not replaced, whatever its name (a dataset
    // without its extension was overwritten); a model file is.
    fs::copy(dir.path().join("d.bin"), dir.path().join("datanoext")).unwrap();
    let o = stcvae(
        &["train", "--config", "train.toml", "--out", "datanoext"],
        dir.path(),
    );
    assert!(
        !o.status.success()
            && stderr(&o).contains("datanoext: exists and is not an stcvae model file"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        fs::read(dir.path().join("datanoext")).unwrap(),
        fs::read(dir.path().join("d.bin")).unwrap()
    );
}

/// A model whose loss rose above its untrained network's is not written (it was, with a
/// warning and exit status 0, and `train && render` went on to render with it); its
/// checkpoints are, and `--resume --keep-diverged` writes it from them without training
/// again. At lr 0.999 for 300 steps the loss of PathGen with hidden layers [32, 32] rises
/// from 2.65 to ~1,200 (refused: more than 10 % above the first batch's).
#[test]
fn a_diverged_model_is_written_only_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let cfg = dir.path().join("train.toml");
    replace_in(
        &cfg,
        "lr = 3e-3\nlr_final = 3e-4",
        "lr = 0.999\nlr_final = 0.999",
    );
    replace_in(&cfg, "steps = 30\n", "steps = 300\n");
    replace_in(&cfg, "hidden = [4]\n", "hidden = [32, 32]\n");
    // Each run's success and stderr.
    let train = |extra: &[&str]| {
        let o = stcvae(
            &[&["train", "--config", "train.toml"], extra].concat(),
            dir.path(),
        );
        (o.status.success(), stderr(&o))
    };
    let (ok, err) = train(&[]);
    assert!(
        !ok && err.contains("pathgen's from ")
            && err.contains("training diverged or learned nothing, so no model was written")
            && err.contains("`stcvae train --config train.toml --resume --keep-diverged`"),
        "{err}"
    );
    assert!(!dir.path().join("m.stcvae").exists());
    assert!(!dir.path().join("m.loss.png").exists());
    // Retraining another model would take the diverged PathGen from its checkpoint (written
    // with exit status 0 before): refused before any training.
    let (ok, err) = train(&["--model", "lengthgen", "--fresh"]);
    assert!(
        !ok && err.contains("checkpoints in ck record a loss that rose (pathgen's from ")
            && !err.contains("lengthgen: 300 steps"),
        "{err}"
    );
    assert!(!dir.path().join("m.stcvae").exists());
    let (ok, err) = train(&["--resume", "--keep-diverged"]);
    assert!(
        ok && err.contains("written as --keep-diverged asks"),
        "{err}"
    );
    ModelSet::load(&dir.path().join("m.stcvae")).unwrap();
}

/// What an aborted checkpoint save leaves (a staging folder, hidden temporaries of the
/// three files) is removed when the model trains again; other files stay. Models that
/// learn are not refused for a rising loss.
#[test]
fn stale_save_temporaries_are_removed() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let ck = dir.path().join("ck");
    fs::create_dir_all(ck.join(".lengthgen-savingAbC123")).unwrap();
    fs::write(ck.join(".lengthgen-savingAbC123/model.bpk"), b"x").unwrap();
    fs::write(ck.join(".eventgen.json.XyZ987.partial"), b"{").unwrap();
    fs::write(ck.join(".pathgen-optim.bpk.Qq1234.partial"), b"x").unwrap();
    fs::write(ck.join("notes.txt"), b"mine").unwrap();
    let o = stcvae(&["train", "--config", "train.toml"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let mut left: Vec<String> = fs::read_dir(&ck)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.') || n == "notes.txt")
        .collect();
    left.sort();
    // The run's lock file stays (removing a lock file races with the next run's lock).
    assert_eq!(left, [".train.lock", "notes.txt"]);
    assert!(!stderr(&o).contains("loss rose"), "{}", stderr(&o));
    // 3,001 walks and 30 steps: nothing to memorise yet.
    assert!(!stderr(&o).contains("lie above"), "{}", stderr(&o));
}

/// `--resume` from nothing, or from a damaged checkpoint, is refused (the first started
/// afresh without a word, the second loaded the damaged weights); a run's final loss is
/// its last step's (a run shorter than the logging interval reported its first step's);
/// and `steps = 0` is refused rather than trained as one step.
#[test]
fn resume_needs_an_intact_checkpoint_and_the_last_loss_is_the_last_steps() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    replace_in(&dir.path().join("train.toml"), "steps = 30", "steps = 5");
    let base = root().join("models/default.stcvae");
    let base_s = base.to_str().unwrap();
    // `train_eventgen` with more flags (--resume or --fresh, --steps-scale).
    let eventgen_with_all = |d: &Path, flags: &[&str]| {
        let mut args = vec![
            "train",
            "--config",
            "train.toml",
            "--model",
            "eventgen",
            "--base",
            base_s,
        ];
        args.extend_from_slice(flags);
        stcvae(&args, d)
    };
    let eventgen_with = |d: &Path, flag: &str| eventgen_with_all(d, &[flag]);
    let resume = |d: &Path| eventgen_with(d, "--resume");
    let out = resume(dir.path());
    assert!(!out.status.success());
    assert!(stderr(&out).contains("no checkpoint"), "{}", stderr(&out));

    let out = train_eventgen(dir.path(), base_s);
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    let info: serde_json::Value =
        serde_json::from_slice(&fs::read(dir.path().join("ck/eventgen.json")).unwrap()).unwrap();
    let history = info["history"].as_array().unwrap();
    assert_eq!(history.last().unwrap()[0], 5, "{history:?}");
    assert_eq!(history.len(), 2, "{history:?}");

    // An intact checkpoint resumes (nothing left to train: it exports at once).
    let out = resume(dir.path());
    assert!(out.status.success(), "resume failed: {}", stderr(&out));
    assert!(!stderr(&out).contains("past the"), "{}", stderr(&out));
    // All three resumed with EventGen's checkpoint alone: the other two start here, and
    // only EventGen's note counts the seconds of earlier runs (all three said so).
    let out = stcvae(&["train", "--config", "train.toml", "--resume"], dir.path());
    assert!(out.status.success(), "resume failed: {}", stderr(&out));
    let notes = ModelSet::load(&dir.path().join("m.stcvae"))
        .unwrap()
        .training
        .notes;
    let line = |k: &str| {
        notes
            .split("; ")
            .find(|l| l.starts_with(&format!("{k}: ")))
            .unwrap_or_else(|| panic!("no {k} note in {notes}"))
            .to_owned()
    };
    assert!(line("eventgen").ends_with("over all its runs"), "{notes}");
    assert!(!line("lengthgen").contains("over all its runs"), "{notes}");
    assert!(!line("pathgen").contains("over all its runs"), "{notes}");
    // The notes come in the models' order, not the order they finished in (EventGen, at
    // its end already, finishes first here, and its note came first).
    let at = |k: &str| notes.find(&format!("{k}: ")).unwrap();
    assert!(
        at("lengthgen") < at("pathgen") && at("pathgen") < at("eventgen"),
        "{notes}"
    );
    // Checkpoints of all three now: leave only EventGen's for what follows.
    for k in ["lengthgen", "pathgen"] {
        for f in [
            format!("{k}.json"),
            format!("{k}.bpk"),
            format!("{k}-optim.bpk"),
        ] {
            fs::remove_file(dir.path().join("ck").join(f)).unwrap();
        }
    }
    // Fewer steps than the checkpoint has done (5 × 0.6): exported as it is, and said so.
    let out = eventgen_with_all(dir.path(), &["--resume", "--steps-scale", "0.6"]);
    assert!(out.status.success(), "resume failed: {}", stderr(&out));
    assert!(
        stderr(&out).contains("eventgen's checkpoint was already at step 5, past the 3 steps"),
        "{}",
        stderr(&out)
    );
    // A new run over it must say what becomes of it: refused before any work without
    // --resume or --fresh (it would replace the checkpoint), and --fresh starts over.
    let out = train_eventgen(dir.path(), base_s);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("holds checkpoints of eventgen") && err.contains("--fresh"),
        "{err}"
    );
    let fresh = eventgen_with(dir.path(), "--fresh");
    assert!(fresh.status.success(), "--fresh failed: {}", stderr(&fresh));
    // A config whose architecture changed since the checkpoint: one line that says so,
    // not burn's list of every mismatched tensor.
    let cfg = dir.path().join("train.toml");
    replace_in(&cfg, "hidden = [4, 4]", "hidden = [4, 6]");
    let out = resume(dir.path());
    assert!(!out.status.success());
    let err = stderr(&out);
    let line = err.lines().find(|l| l.starts_with("error:")).unwrap_or("");
    assert!(
        line.contains("eventgen.bpk: ")
            && line.contains("layer shapes differ from the config's [eventgen]")
            && line.len() < 300,
        "{err}"
    );
    replace_in(&cfg, "hidden = [4, 6]", "hidden = [4, 4]");
    // An edited record (what its checksums do not cover): a time or a step no run
    // writes is refused by name, not carried into the reports and the model's notes; so
    // is an emptied history (a final loss of NaN) and a standardisation no model file
    // may hold (reported under the model file's name, after the data was read).
    let record = dir.path().join("ck/eventgen.json");
    let kept = fs::read_to_string(&record).unwrap();
    for (field, value, says) in [
        ("/seconds", serde_json::json!(-1e308), "seconds = -1e308"),
        (
            "/step",
            serde_json::json!(u64::MAX),
            "step = 18446744073709551615",
        ),
        (
            "/history",
            serde_json::json!([]),
            "history does not begin at step 1",
        ),
        // A step beyond the run's, within 2^40: taken for a finished run and written into
        // the model file's notes.
        (
            "/step",
            serde_json::json!(999_999_999u64),
            "step = 999999999 is 1000 or more past the history's last entry (step 5)",
        ),
        (
            "/norm/out_scale/0",
            serde_json::json!(0.0),
            "norm: out_scale[0] = 0 is out of range",
        ),
        // Xoshiro's all-zero state, which it never leaves: the latent noise's normal
        // sampler looped on it for ever (a hang Ctrl-C could not stop).
        (
            "/stream/rng/s",
            serde_json::json!([0, 0, 0, 0]),
            "stream.rng is the all-zero state",
        ),
        // A sum whose mean is beyond f32: reported as a final loss of inf.
        (
            "/stream/pending_loss",
            serde_json::json!([1e308, 1]),
            "stream.pending_loss = (1e308, 1)",
        ),
        // A sum of no readings: added into the next report's mean, a wrong finite loss.
        (
            "/stream/pending_loss",
            serde_json::json!([5.0, 0]),
            "stream.pending_loss = (5, 0)",
        ),
        // Ranges (which become the model file's): replaced by the dataset's on --resume
        // without a word; in a checkpoint taken as another run's decoder, reversed ones
        // were reported as not overlapping the dataset's and [-5, 5] was taken.
        (
            "/ranges/tau",
            serde_json::json!([5.0, 1.0]),
            "ranges.tau = [5.0, 1.0]: expected 0 <= lo <= hi <= 1000",
        ),
        (
            "/ranges/g",
            serde_json::json!([-5.0, 5.0]),
            "ranges.g = [-5.0, 5.0]: expected -0.999 <= lo <= hi <= 0.999",
        ),
        (
            "/ranges/albedo",
            serde_json::json!([0.5, 1.5]),
            "ranges.albedo = [0.5, 1.5]",
        ),
    ] {
        let mut v: serde_json::Value = serde_json::from_str(&kept).unwrap();
        *v.pointer_mut(field).unwrap() = value;
        fs::write(&record, v.to_string()).unwrap();
        let out = resume(dir.path());
        assert!(!out.status.success());
        let err = stderr(&out);
        assert!(
            err.contains("eventgen.json") && err.contains(says) && err.contains("--fresh"),
            "{err}"
        );
    }
    fs::write(&record, kept).unwrap();
    let weights = dir.path().join("ck/eventgen.bpk");
    let mut bytes = fs::read(&weights).unwrap();
    let i = bytes.len() / 2;
    bytes[i] ^= 0x10;
    fs::write(&weights, bytes).unwrap();
    let out = resume(dir.path());
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("eventgen.bpk")
            && stderr(&out).contains("checksum")
            // The advice leads somewhere: a run without --resume would be refused too.
            && stderr(&out).contains("start over with --fresh --model eventgen"),
        "{}",
        stderr(&out)
    );

    // Record files burn's loader or the optimiser panicked on (a tensor of another type, an
    // optimiser state of another shape than its parameter's), their checksums dropped from
    // the record as a checkpoint from before them has none: one line naming the
    // checkpoint, no panic.
    let fresh = eventgen_with(dir.path(), "--fresh");
    assert!(fresh.status.success(), "--fresh failed: {}", stderr(&fresh));
    let kept_record = fs::read_to_string(&record).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&kept_record).unwrap();
    v.as_object_mut().unwrap().remove("crc32");
    let optim = dir.path().join("ck/eventgen-optim.bpk");
    // The first tensor shape [a, b] with a ≠ b (CBOR: "shape", an array of two, two small
    // integers) is written [b, a].
    let swapped = |mut bytes: Vec<u8>| {
        let at = bytes
            .windows(8)
            .position(|w| &w[..6] == b"shape\x82" && w[6] < 0x18 && w[7] < 0x18 && w[6] != w[7])
            .expect("a tensor of two unequal dimensions");
        bytes.swap(at + 6, at + 7);
        bytes
    };
    let retyped = |bytes: Vec<u8>| {
        let text = b"dtypecF32";
        let at = bytes
            .windows(text.len())
            .position(|w| w == text)
            .expect("an f32 tensor");
        let mut bytes = bytes;
        bytes[at + 6..at + 9].copy_from_slice(b"I32");
        bytes
    };
    for (file, edit, says) in [
        (
            &weights,
            &retyped as &dyn Fn(Vec<u8>) -> Vec<u8>,
            "eventgen.bpk: cannot be read",
        ),
        (&optim, &swapped, "eventgen's training stopped on an error"),
    ] {
        let kept_file = fs::read(file).unwrap();
        fs::write(file, edit(kept_file.clone())).unwrap();
        fs::write(&record, v.to_string()).unwrap();
        // One step more than the checkpoint holds, so that the optimiser takes a step.
        replace_in(&dir.path().join("train.toml"), "steps = 5", "steps = 6");
        let out = resume(dir.path());
        replace_in(&dir.path().join("train.toml"), "steps = 6", "steps = 5");
        assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
        let err = stderr(&out);
        assert!(
            err.contains(says)
                && err.contains("--fresh --model eventgen")
                && !err.contains("panicked"),
            "{err}"
        );
        fs::write(file, kept_file).unwrap();
        fs::write(&record, &kept_record).unwrap();
    }

    replace_in(&dir.path().join("train.toml"), "steps = 5", "steps = 0");
    fs::remove_dir_all(dir.path().join("ck")).unwrap();
    let out = train_eventgen(dir.path(), base_s);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("steps"), "{}", stderr(&out));
}

/// Decoders taken from checkpoints into a model file must have been trained the file's
/// way and bound its ranges: a checkpoint's mode is checked before any training, and the
/// file's ranges are narrowed to what the checkpoints saw (they were the new dataset's
/// alone: a LengthGen retrained on τ ≤ 30 beside PathGen and EventGen of τ ≤ 10 gave a file
/// whose default max_tau was 30).
#[test]
fn checkpoint_decoders_keep_their_mode_and_ranges() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    let cfg = d.join("train.toml");
    replace_in(&cfg, "steps = 30", "steps = 5");
    replace_in(&d.join("data.toml"), "max = 30.0", "max = 10.0");
    let train = |extra: &[&str]| {
        let mut args = vec!["train", "--config", "train.toml"];
        args.extend_from_slice(extra);
        stcvae(&args, d)
    };
    // EventGen with a latent the GPU kernels cannot hold (latent + 6 outputs > 16): it
    // trains, with a warning that says so first.
    replace_in(
        &cfg,
        "latent = 2\nhidden = [4, 4]",
        "latent = 11\nhidden = [4, 4]",
    );
    let out = train(&[]);
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    let err = stderr(&out);
    let warning = err
        .lines()
        .find(|l| l.contains("eventgen.latent"))
        .unwrap_or("");
    assert!(
        warning.starts_with(
            "warning: train.toml: eventgen.latent = 11: the model is too large \
             for the GPU kernels"
        ) && warning.ends_with("it will render on the CPU only")
            && !err.contains("lengthgen.latent"),
        "{err}"
    );
    let narrow_tau = ModelSet::load(&d.join("m.stcvae"))
        .unwrap()
        .training
        .tau_range;
    assert!(narrow_tau[1] <= 10.0, "{narrow_tau:?}");

    // The same checkpoints under a learned-mode config: refused, naming the mode, before
    // the dataset is even read (its file is gone and would be generated first).
    fs::remove_file(d.join("d.bin")).unwrap();
    let text = fs::read_to_string(&cfg).unwrap();
    fs::write(&cfg, format!("single_scattering = \"learned\"\n{text}")).unwrap();
    let out = train(&["--model", "lengthgen", "--fresh"]);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("the pathgen checkpoint")
            && err.contains("trained with single_scattering = exact and the config says learned"),
        "{err}"
    );
    assert!(!d.join("d.bin").exists(), "the dataset was generated first");

    // Back to exact, LengthGen retrained on τ up to 30: the file keeps PathGen's and
    // EventGen's τ ≤ 10.
    fs::write(&cfg, text).unwrap();
    replace_in(&d.join("data.toml"), "max = 10.0", "max = 30.0");
    let out = train(&["--model", "lengthgen", "--fresh"]);
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    let (_, rows) = scatter_sim::dataset::read_dataset(&d.join("d.bin")).unwrap();
    let wide = rows.iter().map(|r| r.tau as f64).fold(0.0, f64::max);
    assert!(wide > 20.0, "the new dataset's tau reaches {wide}");
    let set = ModelSet::load(&d.join("m.stcvae")).unwrap();
    assert_eq!(
        set.training.tau_range[1], narrow_tau[1],
        "{:?}",
        set.training
    );
    assert!(set.training.notes.contains("pathgen: from checkpoint"));
}

/// One model's failure stops the others at their next step, each with a checkpoint, and
/// the error names the failing model's checkpoint: they trained on to their end (40
/// minutes at the default size) before it was shown. Here LengthGen's checkpoint no longer
/// fits its architecture, so its resume fails as it loads, while PathGen and EventGen
/// would train on for 20,000 steps.
#[test]
fn one_failing_model_stops_the_others() {
    let dir = tempfile::tempdir().unwrap();
    setup_and_train(dir.path());
    let cfg = dir.path().join("train.toml");
    let text = fs::read_to_string(&cfg).unwrap();
    let text = text
        .replacen("hidden = [4]", "hidden = [4, 4, 4]", 1)
        .replace("steps = 30", "steps = 20000");
    fs::write(&cfg, text).unwrap();
    let o = stcvae(&["train", "--config", "train.toml", "--resume"], dir.path());
    let err = stderr(&o);
    // An error, not an interrupt: 1, not Ctrl-C's 130.
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("lengthgen.bpk") && err.contains("the other models stopped"),
        "{err}"
    );
    for m in ["pathgen", "eventgen"] {
        let json: serde_json::Value = serde_json::from_str(
            &fs::read_to_string(dir.path().join(format!("ck/{m}.json"))).unwrap(),
        )
        .unwrap();
        let step = json["step"].as_u64().unwrap();
        assert!((30..20000).contains(&step), "{m} at step {step}");
    }
}

/// `--fresh` removes the checkpoints of the models it trains as it starts: a run that
/// diverged before its first save left the earlier run's LengthGen checkpoint in place,
/// and `--resume` would have continued that one as if it were this run's (a divergence
/// cannot be forced within the config's bounds, so the test watches the checkpoint go
/// while the run trains toward a first save it never reaches, then stops it). The models
/// not trained keep theirs.
#[cfg(unix)]
#[test]
fn fresh_removes_the_checkpoints_it_replaces() {
    let dir = tempfile::tempdir().unwrap();
    setup_and_train(dir.path());
    let json = dir.path().join("ck/lengthgen.json");
    assert!(json.exists());
    let cfg = dir.path().join("train.toml");
    replace_in(
        &cfg,
        "checkpoint_dir = \"ck\"\n",
        "checkpoint_dir = \"ck\"\ncheckpoint_every = 1000000\n",
    );
    replace_in(&cfg, "steps = 30", "steps = 2000000");
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args([
            "train",
            "--config",
            "train.toml",
            "--model",
            "lengthgen",
            "--fresh",
        ])
        .current_dir(dir.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let gone = || !json.exists();
    common::interrupt_when(&child, gone, std::time::Duration::ZERO, 1, "train --fresh");
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "{}", stderr(&out));
    assert!(dir.path().join("ck/pathgen.json").exists());
    // The advice is a command that runs: "the same command with --resume" was
    // `--fresh --resume`, which the argument parser refuses (exit 2).
    let err = stderr(&out);
    let line = err
        .lines()
        .find_map(|l| l.split_once("go on with: stcvae "))
        .unwrap_or_else(|| panic!("no resume command in: {err}"))
        .1;
    assert_eq!(line, "train --config train.toml --model lengthgen --resume");
    // Resumed under another plan (here --steps-scale, as a run started scaled and resumed
    // without it), the unfinished run is refused, naming both: its learning rate would
    // jump mid-decay. The refusal also shows the advice parses.
    let mut args = common::words(line);
    args.extend(["--steps-scale", "0.5"]);
    let out = stcvae(&args, dir.path());
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("the checkpoint's run stopped at step ")
            && err.contains(
                "of 2000000 and was started with steps = 2000000; this run has steps = 1000000"
            ),
        "{err}"
    );
    // Taken into a model file by a run scaled down to 1 step, the checkpoint is unfinished
    // by its own run's steps (it read as finished against the scaled steps, unsaid).
    let out = stcvae(
        &[
            "train",
            "--config",
            "train.toml",
            "--model",
            "pathgen",
            "--steps-scale",
            "1e-7",
            "--fresh",
        ],
        dir.path(),
    );
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("note: lengthgen comes from its checkpoint at step ")
            && err.contains(
                " of 2000000: an unfinished training (train it on with --model lengthgen \
                 --resume and the settings it was started with)"
            ),
        "{err}"
    );
}

/// A dataset whose every walk has albedo 0 has no event for EventGen in exact mode (the
/// reservoir keeps the centre, which exact mode draws itself): the refusal names the
/// albedo, where it used to advise a larger tau or more samples, which cannot help.
#[test]
fn albedo_zero_data_is_refused_for_eventgen_naming_the_albedo() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    replace_in(
        &dir.path().join("data.toml"),
        "albedo = { kind = \"one-minus-power\", epsilon = 1e-6, exponent = 6.0 }",
        "albedo = { kind = \"fixed\", value = 0.0 }",
    );
    let base = root().join("models/default.stcvae");
    let out = train_eventgen(dir.path(), base.to_str().unwrap());
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains(
            "d.bin: none of its 3001 walks is usable for eventgen (every walk has albedo 0"
        ),
        "{err}"
    );
    assert!(!err.contains("larger tau"), "{err}");
}

/// Walks that could not make a model file (all at τ = 0: its training range must reach
/// above 0) are refused before the training, naming the dataset; they used to be trained
/// in full and then refused with "nothing written". The paper's learned mode, so that the
/// walks of N = 1 (every walk at τ = 0) are used at all.
#[test]
fn a_dataset_that_cannot_make_a_model_file_is_refused_before_training() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    replace_in(
        &dir.path().join("data.toml"),
        "tau = { kind = \"power\", max = 30.0, exponent = 3.0 }",
        "tau = { kind = \"fixed\", value = 0.0 }",
    );
    replace_in(
        &dir.path().join("train.toml"),
        "checkpoint_dir = \"ck\"\n",
        "checkpoint_dir = \"ck\"\nsingle_scattering = \"learned\"\n",
    );
    let out = stcvae(&["train", "--config", "train.toml"], dir.path());
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("d.bin: its walks cannot make a model file: training.tau_range = [0.0, 0.0]"),
        "{err}"
    );
    assert!(
        !dir.path().join("ck").exists(),
        "checkpoints written: {err}"
    );
}

/// A learned-mode run (the paper's way: the models learn the walks of N = 1 too) writes a
/// learned-mode file, and checkpoints that say so: read as exact, its N = 1 walks would be
/// drawn twice, once by the sampler with probability e^(−τ) and again by a LengthGen that
/// learned them (a brighter image, without a word). Every other run of these tests trains
/// in exact mode, the default, where a file written "exact" whatever the config said
/// passed them.
#[test]
fn a_learned_mode_run_writes_a_learned_mode_file() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let cfg = dir.path().join("train.toml");
    replace_in(&cfg, "steps = 30", "steps = 5");
    replace_in(
        &cfg,
        "checkpoint_dir = \"ck\"\n",
        "checkpoint_dir = \"ck\"\nsingle_scattering = \"learned\"\n",
    );
    let out = stcvae(&["train", "--config", "train.toml"], dir.path());
    assert!(out.status.success(), "train failed: {}", stderr(&out));
    let set = ModelSet::load(&dir.path().join("m.stcvae")).unwrap();
    assert_eq!(
        set.single_scattering,
        cvae::model_file::SingleScattering::Learned
    );
    for k in ["lengthgen", "pathgen", "eventgen"] {
        let info: serde_json::Value =
            serde_json::from_slice(&fs::read(dir.path().join(format!("ck/{k}.json"))).unwrap())
                .unwrap();
        assert_eq!(info["single_scattering"], "learned", "{k}");
    }
}

/// A model record without its checkpoint JSON (removed by hand, or a kill between a first
/// save's renames) cannot be resumed: `--resume` used to train that model from the start
/// and a plain run to write over the record, both without a word. Both are refused naming
/// the file; `--fresh` removes it and trains.
#[test]
fn a_checkpoint_record_without_its_json_is_named() {
    let dir = tempfile::tempdir().unwrap();
    setup_and_train(dir.path());
    fs::remove_file(dir.path().join("ck/lengthgen.json")).unwrap();
    for args in [
        &["train", "--config", "train.toml", "--resume"][..],
        &["train", "--config", "train.toml", "--model", "lengthgen"][..],
    ] {
        let o = stcvae(args, dir.path());
        assert!(!o.status.success(), "{args:?} was accepted");
        let err = stderr(&o);
        assert!(
            err.contains("lengthgen.bpk: a checkpoint record without its lengthgen.json")
                && err.contains("--fresh --model lengthgen"),
            "{args:?}: {err}"
        );
    }
    let o = stcvae(
        &[
            "train",
            "--config",
            "train.toml",
            "--model",
            "lengthgen",
            "--fresh",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.path().join("ck/lengthgen.json").exists());
}

/// A second run on a checkpoint_dir that another training holds is refused before it
/// removes or writes anything there; once the holder is gone the same run trains. The
/// test holds the lock itself (the lock a run takes: an advisory lock on ck/.train.lock).
#[test]
fn a_checkpoint_dir_in_use_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let ck = dir.path().join("ck");
    fs::create_dir_all(&ck).unwrap();
    let stale = ck.join(".lengthgen.bpk.abc123.partial");
    fs::write(&stale, b"another run's save under way").unwrap();
    let holder = fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(ck.join(".train.lock"))
        .unwrap();
    holder.lock().unwrap();
    let o = stcvae(&["train", "--config", "train.toml", "--fresh"], dir.path());
    let err = stderr(&o);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("checkpoint_dir = ck is in use by another `stcvae train`"),
        "{err}"
    );
    assert!(stale.exists(), "the holder's temporaries are left alone");
    // Refused before any work: the missing dataset was not generated.
    assert!(!dir.path().join("d.bin").exists());
    drop(holder);
    let o = stcvae(&["train", "--config", "train.toml", "--fresh"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(ck.join("lengthgen.json").is_file());
}

/// A run that reads no validation loss (10 walks: under the 20 rows a validation needs)
/// writes no loss curves, and an earlier run's plot under the model's name goes with a
/// note: it stayed beside the new model as if it were its curves.
#[test]
fn an_earlier_runs_loss_curves_do_not_stay_beside_a_new_model() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    replace_in(&dir.path().join("data.toml"), "walks = 3001", "walks = 10");
    let stale = dir.path().join("m.loss.png");
    fs::write(&stale, b"an earlier run's curves").unwrap();
    let o = stcvae(&["train", "--config", "train.toml"], dir.path());
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("it trains without a validation loss"), "{err}");
    assert!(
        err.contains("note: removed m.loss.png: an earlier run's loss curves"),
        "{err}"
    );
    assert!(!stale.exists());
    assert!(dir.path().join("m.stcvae").is_file());
}

/// A run that memorises its dataset is told so: 40 walks trained 3,000 steps with a wide
/// latent, EventGen's losses on held-out walks (the run's next walks) lie far above its
/// losses on training walks (z = 11.4 measured over its 23 rows; the warning's bar is 4).
/// The loss curves are plotted beside the model file, and the final held-out loss is in
/// the summary.
#[test]
fn a_memorising_run_is_warned_and_its_loss_curves_plotted() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    replace_in(&dir.path().join("data.toml"), "walks = 3001", "walks = 40");
    let cfg = dir.path().join("train.toml");
    let text = fs::read_to_string(&cfg).unwrap();
    let wide = text
        .replace("hidden = [4, 4]", "hidden = [4]")
        .replace(
            "latent = 2\nhidden = [4]",
            "latent = 5\nhidden = [16, 16, 16]",
        )
        .replace("steps = 30", "steps = 3000");
    assert_eq!(wide.matches("steps = 3000").count(), 3);
    assert_eq!(wide.matches("hidden = [16, 16, 16]").count(), 3);
    fs::write(&cfg, wide).unwrap();
    let o = stcvae(&["train", "--config", "train.toml"], dir.path());
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("warning: eventgen's losses on held-out walks")
            && err.contains("it is learning the dataset's walks rather than their distribution"),
        "{err}"
    );
    assert!(err.contains("pathgen: 3000 steps, final loss"), "{err}");
    assert!(err.contains("(held-out "), "{err}");
    assert!(err.contains("loss curves: m.loss.png"), "{err}");
    let png = fs::read(dir.path().join("m.loss.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"), "a PNG");
}
