//! `sample` and `eval` through the binary, and the model's limits as `render` applies them:
//! its training range of τ, g and the albedo, and the steps it is not trusted with.

use super::*;

#[test]
fn sample_writes_generate_columns_with_the_requested_conditions() {
    let d = tempfile::tempdir().unwrap();
    let csv = d.path().join("s.csv");
    ok(&stcvae(&[
        "sample",
        "--tau",
        "5",
        "--g",
        "0.4",
        "--albedo",
        "0.9",
        "--samples",
        "2000",
        "--seed",
        "3",
        "--out",
        csv.to_str().unwrap(),
    ]));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "tau,g,albedo,n,cos_theta,beta,alpha,ev_x,ev_y,ev_z,ev_wx,ev_wy,ev_wz"
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 2000);
    let mut single = 0;
    for r in &rows {
        assert_eq!((r[0], r[1], r[2]), (5.0, 0.4, 0.9));
        assert!(r[3] >= 1.0 && r[4].abs() <= 1.0 && r[5] * r[5] + r[6] * r[6] <= 1.0 + 1e-6);
        single += (r[3] == 1.0) as u32;
    }
    // P(N = 1) = e^{-5} = 0.0067: 13.5 expected of 2000 (Poisson, σ = 3.7). Fewer than 2
    // has probability 2e-5, 30 or more 7e-5: a sampler that never takes the exact branch
    // fails, as does, 3 times in 4, one that takes it 2.5× too often. A smoke test of the
    // command: the branch's probability is checked to |z| < 4 on 10⁵ draws by
    // cvae's model_file.rs (single_scattering_branch_probability).
    assert!(
        (2..30).contains(&single),
        "{single} single-scattering walks"
    );
    // Same seed, same file.
    let csv2 = d.path().join("s2.csv");
    ok(&stcvae(&[
        "sample",
        "--tau",
        "5",
        "--g",
        "0.4",
        "--albedo",
        "0.9",
        "--samples",
        "2000",
        "--seed",
        "3",
        "--out",
        csv2.to_str().unwrap(),
    ]));
    assert_eq!(std::fs::read(&csv).unwrap(), std::fs::read(&csv2).unwrap());
}

/// `sample --seed S` draws the model walks `eval` draws for a setting of seed S, as both
/// helps say: row i is walk i of `cvae::eval::model_columns` at the row's conditions,
/// past the first chunk of 65,536 walks too. A walk index counted from each chunk's start
/// drew the first chunk again (a file of 65,540 rows held 65,536 walks), unseen by the
/// other tests of `sample`, which draw at most 2,000 walks or look only at correlations
/// with `generate`'s rows. Compared: N and the exit (cos θ, β, α) as the CSV holds them,
/// f32; the tolerance of 1e-6 only allows for that rounding (half an f32 step is at most
/// 3e-8 in [-1, 1]), while another walk's cos θ differs by ~0.5.
#[test]
fn sample_draws_evals_walks_past_its_first_chunk() {
    let d = tempfile::tempdir().unwrap();
    let csv = d.path().join("s.csv");
    let model = root().join("models/default.stcvae");
    let n: usize = 65_540;
    let count = n.to_string();
    ok(&stcvae(&[
        "sample",
        "--model",
        model.to_str().unwrap(),
        "--tau",
        "5",
        "--g",
        "0.4",
        "--albedo",
        "0.9",
        "--samples",
        &count,
        "--seed",
        "3",
        "--out",
        csv.to_str().unwrap(),
    ]));
    let m = cvae::ModelSet::load(&model).unwrap();
    let want = cvae::eval::model_columns(&m, 5.0, 0.4, 0.9, n, 3);
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!((rows.len(), want.0[0].len()), (n, n));
    let near = |a: f64, b: f64| (a - b).abs() <= 1e-6;
    // The CSV's columns: tau, g, albedo, n, cos_theta, beta, alpha, …; eval's: N, ln N,
    // cos θ, α, β, ….
    for (i, r) in rows.iter().enumerate() {
        let (n_i, cos, alpha, beta) = (want.0[0][i], want.0[2][i], want.0[3][i], want.0[4][i]);
        assert!(
            r[3] == n_i && near(r[4], cos) && near(r[5], beta) && near(r[6], alpha),
            "row {i}: {r:?}; eval's walk {i}: N {n_i}, cos θ {cos}, β {beta}, α {alpha}"
        );
    }
}

#[test]
fn model_errors_are_one_line() {
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("bad.stcvae");
    std::fs::write(&bad, b"STCVAEMD garbage").unwrap();
    let csv = d.path().join("s.csv");
    // `sample` at τ = 5, g = 0, φ = 1 from `model` into `out`; its error.
    let sample_fails = |model: &Path, out: &Path| {
        fails(&stcvae(&[
            "sample",
            "--model",
            model.to_str().unwrap(),
            "--tau",
            "5",
            "--g",
            "0",
            "--albedo",
            "1",
            "--out",
            out.to_str().unwrap(),
        ]))
    };
    let e = sample_fails(&bad, &csv);
    assert!(
        e.contains("bad.stcvae") && e.trim().lines().count() == 1,
        "{e}"
    );
    let e = fails(&stcvae(&[
        "sample",
        "--tau",
        "5",
        "--g",
        "1.5",
        "--albedo",
        "1",
        "--out",
        csv.to_str().unwrap(),
    ]));
    assert!(e.contains("g") && e.contains("0.999"), "{e}");
    assert!(!csv.exists());
    // A folder as --out is named as one (it used to be told to end in .csv), and the model
    // as --out is refused before it is replaced by walks.
    let model = d.path().join("m.csv");
    std::fs::copy(root().join("models/default.stcvae"), &model).unwrap();
    for (out, needle) in [
        (d.path().to_path_buf(), "is a directory".to_string()),
        (
            model.clone(),
            "is also the model, which the output would replace".to_string(),
        ),
    ] {
        let e = sample_fails(&model, &out);
        assert!(e.contains(&needle) && e.trim().lines().count() == 1, "{e}");
    }
    assert_eq!(
        std::fs::read(&model).unwrap(),
        std::fs::read(root().join("models/default.stcvae")).unwrap()
    );
    // `sample` writes CSV only: another extension is refused, and nothing is written.
    let bin = d.path().join("s.bin");
    let e = sample_fails(&root().join("models/default.stcvae"), &bin);
    assert!(
        e.contains("s.bin: sample writes CSV; name the file *.csv")
            && e.trim().lines().count() == 1,
        "{e}"
    );
    assert!(!bin.exists());
}

/// `sample` warns of each condition outside the model's training range, naming the flag
/// and the range, and of no other (the warnings were tested for `eval` only).
#[test]
fn sample_warns_of_each_condition_outside_the_training_range() {
    let d = tempfile::tempdir().unwrap();
    let mut m = cvae::ModelSet::load(&root().join("models/default.stcvae")).unwrap();
    m.training.tau_range = [2.0, 100.0];
    m.training.g_range = [-0.5, 0.5];
    m.training.albedo_range = [0.95, 1.0];
    let model = d.path().join("narrow.stcvae");
    m.save(&model).unwrap();
    let csv = d.path().join("s.csv");
    let warnings = |tau: &str, g: &str, albedo: &str| -> Vec<String> {
        let err = ok(&stcvae(&[
            "sample",
            "--model",
            model.to_str().unwrap(),
            "--tau",
            tau,
            "--g",
            g,
            "--albedo",
            albedo,
            "--samples",
            "3",
            "--out",
            csv.to_str().unwrap(),
        ]));
        err.lines()
            .filter(|l| l.starts_with("warning:"))
            .map(str::to_owned)
            .collect()
    };
    let x = ": the samples are an extrapolation";
    let range = "lies outside the model's training range";
    assert_eq!(
        warnings("5", "0.4", "0.9"),
        [format!("warning: --albedo 0.9 {range} [0.95, 1]{x}")]
    );
    assert_eq!(
        warnings("1", "-0.7", "1"),
        [
            format!("warning: --tau 1 {range} [2, 100]{x}"),
            format!("warning: --g -0.7 {range} [-0.5, 0.5]{x}"),
        ]
    );
    assert!(warnings("5", "0.4", "1").is_empty());
}

/// `eval --at`: only the given settings, in metrics.md and on stdout, with the table of
/// thin bands near the sphere's surface; a malformed or out-of-range setting is a one-line
/// error naming what is wrong.
#[test]
fn eval_at_given_settings() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("ev");
    let dir_s = dir.to_str().unwrap();
    let out = stcvae(&[
        "eval",
        "--samples",
        "300",
        "--at",
        "5,0.875,1",
        "--at",
        "2,0.5,0.9",
        "--out",
        dir_s,
    ]);
    ok(&out);
    let md = std::fs::read_to_string(dir.join("metrics.md")).unwrap();
    assert_eq!(String::from_utf8_lossy(&out.stdout), md);
    assert!(
        md.contains("| 5 | 0.875 | 1 |") && md.contains("| 2 | 0.5 | 0.9 |"),
        "{md}"
    );
    assert_eq!(md.matches("Events by distance").count(), 2, "{md}");
    assert!(md.contains("half-space NEE, surface behind"), "{md}");
    // The joint (cos θ, α) and (cos θ, β) are compared at φ = 1, in the table and the JSON.
    assert!(md.contains("cos_theta_alpha 2-D KS / sliced W1"), "{md}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("metrics.json")).unwrap()).unwrap();
    let pair = json["max_ks"]["cos_theta_beta"].as_f64().unwrap();
    assert!(pair > 0.0 && pair < 0.5, "{pair}");
    assert!(!dir.join("fig11_n.png").exists(), "--at draws no plots");
    // At φ < 1 alone only the event marginals are measured: the others have no maximum
    // (not a perfect-looking 0), and the summary says so.
    let only = d.path().join("ev_phi");
    ok(&stcvae(&[
        "eval",
        "--samples",
        "300",
        "--at",
        "2,0.5,0.9",
        "--out",
        only.to_str().unwrap(),
    ]));
    let md = std::fs::read_to_string(only.join("metrics.md")).unwrap();
    assert!(
        md.contains(
            "(not measured at these settings: n, cos_theta, alpha, beta, cos_theta_alpha, \
             cos_theta_beta)"
        ),
        "{md}"
    );
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(only.join("metrics.json")).unwrap()).unwrap();
    let max_ks = json["max_ks"].as_object().unwrap();
    assert!(
        !max_ks.contains_key("n") && max_ks.contains_key("event_z"),
        "{max_ks:?}"
    );
    for (at, want) in [
        ("5,0.875", "three numbers"),
        ("5,0.875,1.5", "albedo"),
        ("5,x,1", "TAU,G,ALBEDO"),
        ("-1,0.4,0.9", "tau"),
    ] {
        let e = fails(&stcvae(&["eval", "--at", at, "--out", dir_s]));
        assert!(e.contains(want), "{at}: {e}");
    }
}

/// `eval --at`: setting i is drawn with seed + i, as `--help` and metrics.md say, the seeds
/// the paper's grid gives its settings (`cvae::eval::evaluate_grid`): `--at` the grid's
/// first two settings at seed 4 reports them as the grid at seed 4 does, to the last digit
/// of metrics.json. One seed for every setting, or seeds one off, drew other walks than
/// metrics.md names, unseen by the other `--at` tests, whose figures change with their
/// settings whatever the seeds. 20 walks a side are enough: the figures include
/// distances between continuous samples, which two seeds' walks do not share (measured:
/// the grid's second setting against `--at` of it alone at seed 4, its first against
/// `--at` of it at seed 5, both differ).
#[test]
fn eval_at_draws_setting_i_with_seed_plus_i() {
    let d = tempfile::tempdir().unwrap();
    let settings = |extra: &[&str], out: &str| -> Vec<serde_json::Value> {
        let dir = d.path().join(out);
        let mut args = vec!["eval", "--samples", "20", "--seed", "4"];
        args.extend_from_slice(extra);
        args.extend(["--out", dir.to_str().unwrap()]);
        ok(&stcvae(&args));
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("metrics.json")).unwrap()).unwrap();
        json["settings"].as_array().unwrap().clone()
    };
    let grid = settings(&[], "grid");
    let at = settings(&["--at", "1,-0.7,1", "--at", "1,0,1"], "at");
    assert_eq!((grid.len(), at.len()), (32, 2));
    for (i, (a, g)) in at.iter().zip(&grid).enumerate() {
        assert!(a == g, "--at setting {i}: {a}\ngrid setting {i}: {g}");
    }
}

/// render.max_tau up to the model's training range is taken, the README's max_tau = 300
/// included (the shipped model's range ends at 299.9996); beyond it, a one-line error
/// names the field and the range. Below min_tau (default 1) no sphere step could be
/// taken, and ST-CVAE would be PT under its name: refused too.
#[test]
fn max_tau_is_checked_against_the_training_range() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("s.toml");
    let out = d.path().join("r");
    let args = [
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--integrator",
        "stcvae",
        "--device",
        "cpu",
        "--spp",
        "1",
        "--out",
        out.to_str().unwrap(),
    ];
    for (max_tau, accepted) in [("300.0", true), ("301.0", false), ("0.5", false)] {
        let text =
            sphere_scene_text(8).replace("[render]\n", &format!("[render]\nmax_tau = {max_tau}\n"));
        std::fs::write(&scene, text).unwrap();
        if accepted {
            ok(&stcvae(&args));
        } else {
            let e = fails(&stcvae(&args));
            let needle = if max_tau == "0.5" {
                "render.max_tau = 0.5 is below render.min_tau = 1 (its default): no sphere step could be taken"
            } else {
                "render.max_tau = 301"
            };
            assert!(
                e.contains(needle)
                    && e.contains("[") == (max_tau != "0.5")
                    && e.trim().lines().count() == 1,
                "{e}"
            );
        }
    }
    // The check is ST-CVAE's: an ST-CVAE scene with that max_tau renders with `--integrator
    // pt` (the scene was validated before the command line's overrides, and refused).
    let text = sphere_scene_text(8)
        .replace("[render]\n", "[render]\nmax_tau = 0.5\n")
        .replace("integrator = \"pt\"", "integrator = \"stcvae\"");
    assert!(
        text.contains("integrator = \"stcvae\""),
        "the sphere scene changed"
    );
    std::fs::write(&scene, text).unwrap();
    let mut pt_args = args;
    pt_args[4] = "pt";
    ok(&stcvae(&pt_args));
    let mut no_override = args.to_vec();
    no_override.drain(3..5);
    fails(&stcvae(&no_override));
    // Without max_tau the cap is the model's: a min_tau above it is refused as well.
    let text = sphere_scene_text(8).replace("[render]\n", "[render]\nmin_tau = 400.0\n");
    std::fs::write(&scene, text).unwrap();
    let e = fails(&stcvae(&args));
    assert!(
        e.contains("render.min_tau = 400 is above the model's training maximum")
            && e.contains("(the default max_tau)")
            && e.trim().lines().count() == 1,
        "{e}"
    );
    // Under a model trained below the default min_tau, the message says the 1 is the
    // default: the scene has no min_tau line to look for.
    let mut m = cvae::ModelSet::load(&root().join("models/default.stcvae")).unwrap();
    m.training.tau_range = [0.1, 0.3];
    let thin = d.path().join("thin.stcvae");
    m.save(&thin).unwrap();
    std::fs::write(&scene, sphere_scene_text(8)).unwrap();
    let mut thin_args = args.to_vec();
    thin_args.extend(["--model", thin.to_str().unwrap()]);
    let e = fails(&stcvae(&thin_args));
    assert!(
        e.contains("render.min_tau = 1 (its default) is above the model's training maximum 0.3")
            && e.trim().lines().count() == 1,
        "{e}"
    );
    // Within the tolerance that lets `max_tau = 300` past the shipped model's 299.9996, a
    // min_tau of 300 raises the default cap to it, as writing both would (it was refused
    // alone and rendered with max_tau = 300 beside it).
    let text = sphere_scene_text(8).replace("[render]\n", "[render]\nmin_tau = 300.0\n");
    std::fs::write(&scene, text).unwrap();
    ok(&stcvae(&args));
}

/// For |g| above render_gpu::scene::MODEL_MAX_G (0.98) ST-CVAE takes no step from the
/// models, where they were measured biased (forward and backward): every sphere step's walk
/// is simulated, even with exact_tau = 0 (the models alone), the JSON's exact_tau is null
/// and a note says why. At ±0.98 the models still draw the steps.
#[test]
fn strongly_anisotropic_media_take_no_model_steps() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("s.toml");
    let out = d.path().join("r");
    for (g, trusted) in [
        ("0.98", true),
        ("0.99", false),
        ("-0.98", true),
        ("-0.99", false),
    ] {
        let text = sphere_scene_text(8)
            .replace("g = 0.4", &format!("g = {g}"))
            .replace("[render]\n", "[render]\nexact_tau = 0.0\n");
        assert!(
            text.contains(&format!("g = {g}")),
            "the sphere scene's g changed"
        );
        std::fs::write(&scene, text).unwrap();
        let err = ok(&render_scene(
            &scene,
            "stcvae",
            "3",
            "1",
            &out,
            &["--device", "cpu"],
        ));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
                .unwrap();
        let (steps, exact) = (
            json["stats"]["steps"].as_u64().unwrap(),
            json["stats"]["exact_steps"].as_u64().unwrap(),
        );
        assert!(steps > 0, "g {g}: {json}");
        assert_eq!(
            exact == steps,
            !trusted,
            "g {g}: {steps} steps, {exact} exact"
        );
        assert_eq!(exact == 0, trusted, "g {g}: {steps} steps, {exact} exact");
        assert_eq!(json["exact_tau"].is_null(), !trusted, "g {g}: {json}");
        assert_eq!(err.contains("simulated exactly"), !trusted, "g {g}: {err}");
    }
}

/// Outputs that would replace the command's own model are refused before any work, and
/// the model stays: `eval --out D` with the model at D/metrics.json, `bench render --save D`
/// with it at D/k1_pixels.csv (both replaced it with their results, exit 0).
#[test]
fn eval_and_bench_outputs_never_replace_the_model() {
    let d = tempfile::tempdir().unwrap();
    let shipped = std::fs::read(root().join("models/default.stcvae")).unwrap();
    let model = d.path().join("metrics.json");
    std::fs::write(&model, &shipped).unwrap();
    let out = stcvae(&[
        "eval",
        "--model",
        model.to_str().unwrap(),
        "--at",
        "5,0.4,1",
        "--samples",
        "50",
        "--out",
        d.path().to_str().unwrap(),
    ]);
    let err = fails(&out);
    assert!(err.contains("metrics.json is also --model"), "{err}");
    assert_eq!(std::fs::read(&model).unwrap(), shipped);
    let save = d.path().join("save");
    std::fs::create_dir(&save).unwrap();
    let model = save.join("k1_pixels.csv");
    std::fs::write(&model, &shipped).unwrap();
    let scene = sphere_scene_file(d.path(), 8);
    let out = stcvae(&[
        "bench",
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--k",
        "1",
        "--spp",
        "6",
        "--size",
        "8",
        "--device",
        "cpu",
        "--model",
        model.to_str().unwrap(),
        "--save",
        save.to_str().unwrap(),
    ]);
    let err = fails(&out);
    assert!(err.contains("k1_pixels.csv is also the model"), "{err}");
    assert_eq!(std::fs::read(&model).unwrap(), shipped);
}

/// exact_tau lowered below its default in a forward medium (g >= 0.9) is warned about:
/// the models then draw the thin steps, measured biased there (-30 % in an absorbing
/// channel at g = 0.95); not at the default exact_tau, nor at g = 0.4, nor for PT.
#[test]
fn lowered_exact_tau_in_forward_media_is_warned() {
    let d = tempfile::tempdir().unwrap();
    let run = |g: &str, exact: &str, integrator: &str| {
        let text = sphere_scene_text(8)
            .replace("g = 0.4", &format!("g = {g}"))
            .replace("[render]\n", &format!("[render]\n{exact}"));
        let scene = d.path().join("s.toml");
        std::fs::write(&scene, text).unwrap();
        let out = stcvae(&[
            "render",
            scene.to_str().unwrap(),
            "--integrator",
            integrator,
            "--spp",
            "1",
            "--device",
            "cpu",
            "--out",
            d.path().join("r").to_str().unwrap(),
        ]);
        ok(&out).contains("with medium.g")
    };
    assert!(run("0.95", "exact_tau = 0.0\n", "stcvae"));
    assert!(run("0.9", "exact_tau = 5.0\n", "stcvae"));
    assert!(!run("0.95", "", "stcvae"));
    assert!(!run("0.4", "exact_tau = 0.0\n", "stcvae"));
    assert!(!run("0.95", "exact_tau = 0.0\n", "pt"));
}

/// The models draw the sphere steps from max(min_tau, exact_tau) up: a model trained from
/// τ = 30 used from 20 (the default exact_tau) extrapolates, and `render` says so, as it
/// does for g and the albedo; the shipped model, trained from τ ≈ 0, is not warned.
#[test]
fn model_steps_below_the_trained_taus_are_warned() {
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 8);
    let mut m = cvae::ModelSet::load(&root().join("models/default.stcvae")).unwrap();
    let render = |model: &Path| {
        stcvae(&[
            "render",
            "--scene",
            scene.to_str().unwrap(),
            "--integrator",
            "stcvae",
            "--model",
            model.to_str().unwrap(),
            "--spp",
            "1",
            "--device",
            "cpu",
            "--out",
            d.path().join("r").to_str().unwrap(),
        ])
    };
    let out = render(&root().join("models/default.stcvae"));
    ok(&out);
    assert!(
        !common::stderr(&out).contains("sphere steps from"),
        "{}",
        common::stderr(&out)
    );
    m.training.tau_range[0] = 30.0;
    let file = d.path().join("from30.stcvae");
    m.save(&file).unwrap();
    let out = render(&file);
    ok(&out);
    let err = common::stderr(&out);
    assert!(
        err.contains("sphere steps from τ = 20 (render.min_tau/exact_tau; trained [30, ")
            && err.contains("outside the model's training range: ST-CVAE extrapolates there"),
        "{err}"
    );
}
