//! Every experiment config parses and runs in `--quick` mode end to end, producing its CSV
//! (every figure finite), its plots (valid PNGs) and a report whose images exist.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn configs() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(root().join("configs/experiments"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

fn check_png(path: &Path) {
    let (width, height, _) = common::read_png(path);
    assert!(width > 0 && height > 0, "{}", path.display());
}

/// `stcvae experiment CFG --quick --device cpu --out OUT`, run from the repository root.
fn quick_experiment(cfg: &Path, out: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args([
            "experiment",
            cfg.to_str().unwrap(),
            "--quick",
            "--device",
            "cpu",
            "--out",
        ])
        .arg(out)
        .current_dir(root())
        .output()
        .unwrap()
}

#[test]
fn every_experiment_runs_quick() {
    let names = [
        "absorption",
        "complexity",
        "distributions",
        "fallback",
        "nee",
        "quality",
        "teaser",
        "teaser_no_nee",
    ];
    let found: Vec<String> = configs()
        .iter()
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(found, names, "one config per paper result");
    let tmp = tempfile::tempdir().unwrap();
    for cfg in configs() {
        let out = quick_experiment(&cfg, tmp.path());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{}: {err}", cfg.display());
        // A quick run's own folder: it wrote over a full run's results in the same one.
        let name = cfg.file_stem().unwrap().to_string_lossy();
        let dir = tmp.path().join(format!("{name}-quick"));
        let csv = std::fs::read_to_string(dir.join("figures.csv")).unwrap();
        let mut lines = csv.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let mut rows = 0;
        for line in lines {
            let cells = csv_cells(line);
            assert_eq!(cells.len(), header.len(), "{}: {line}", cfg.display());
            for (h, c) in header.iter().zip(&cells) {
                if let Ok(v) = c.parse::<f64>() {
                    assert!(v.is_finite(), "{}: {h} = {c}", cfg.display());
                }
            }
            rows += 1;
        }
        assert!(rows > 0, "{}: no figures", cfg.display());
        if name == "nee" {
            // Labels keep their commas (quoted), as report.md has them.
            assert!(csv.contains("\"PT, no NEE\","), "{csv}");
        }
        if name == "fallback" {
            // Each threshold in both modes: exact walks below exact_tau = 20 (most of the
            // bunny's steps at ×4), none with exact_tau = 0.
            let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
            let (col, events) = (
                column("st_exact_steps_per_path"),
                column("st_exact_walk_events_per_path"),
            );
            let (mut exact, mut drawn) = (0, 0);
            for line in csv.lines().skip(1) {
                let cells = csv_cells(line);
                let v: f64 = cells[col].parse().unwrap();
                // A walk has at least one event (its centre).
                let e: f64 = cells[events].parse().unwrap();
                if cells[0].contains("exact_tau = 0") {
                    assert_eq!((v, e), (0.0, 0.0), "{line}");
                    drawn += 1;
                } else {
                    assert!(v > 0.0 && e >= v, "{line}");
                    exact += 1;
                }
            }
            assert!(exact > 0 && exact == drawn, "{csv}");
        }
        if name == "complexity" {
            // The work maps' EXRs hold the counts per path (their PNGs the log scale): each
            // half's mean over the pixels, which all trace as many paths, is the table's
            // figure per path (PT events left; ST-CVAE steps plus fallback events right) up
            // to the f32 rounding of the per-pixel counts (1e-4 relative allowed). A map
            // scaled for display (0–1) misses the bunny's counts, tens per path, by far.
            let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
            let mut maps = 0;
            let mut drawn = std::collections::BTreeMap::new();
            for line in csv.lines().skip(1) {
                let cells = csv_cells(line);
                let (obj, k) = (cells[column("object")].as_str(), &cells[column("density")]);
                let file = dir.join(format!("work_{obj}_k{k}.exr"));
                let (img, tag) = render_gpu::image_io::read_exr(&file)
                    .unwrap_or_else(|e| panic!("every row has its map: {e}"));
                assert!(tag.is_none(), "{}: a map, not a render", file.display());
                let half = (img.width - 2) / 2;
                // The 2-pixel gap between the halves holds no count.
                for y in 0..img.height {
                    for x in half..half + 2 {
                        assert_eq!(
                            img.pixels[y * img.width + x],
                            [0.0; 3],
                            "{}",
                            file.display()
                        );
                    }
                }
                let mean = |x0: usize| {
                    let mut sum = 0.0;
                    for y in 0..img.height {
                        for x in x0..x0 + half {
                            sum += img.pixels[y * img.width + x][0] as f64;
                        }
                    }
                    sum / (half * img.height) as f64
                };
                let figure = |name: &str| cells[column(name)].parse::<f64>().unwrap();
                let pt = figure("pt_events_per_path");
                let st = figure("st_steps_per_path") + figure("st_fallback_events_per_path");
                // The speed-up is PT's time over ST-CVAE's, as in the other tables: the CSV
                // holds the times and the ratio at full precision (`{v}` round-trips an
                // f64), so they agree to rounding (1e-9 relative allowed); ST-CVAE's over
                // PT's is off by the ratio squared.
                let ratio = figure("pt_seconds") / figure("st_seconds");
                assert!(
                    (figure("speedup") - ratio).abs() <= 1e-9 * ratio,
                    "{}: speedup {} against pt_seconds / st_seconds = {ratio}",
                    file.display(),
                    figure("speedup")
                );
                for (what, map, table) in [("PT", mean(0), pt), ("ST-CVAE", mean(half + 2), st)] {
                    assert!(
                        (map - table).abs() <= 1e-4 * table && table > 0.0,
                        "{}: {what}'s map holds {map} per path, the table {table}",
                        file.display()
                    );
                }
                maps += 1;
                let png = dir.join(format!("work_{obj}_k{k}.png"));
                drawn
                    .entry(obj.to_string())
                    .or_insert_with(Vec::new)
                    .push((img, png));
            }
            assert_eq!(maps, csv.lines().count() - 1, "a work map for every row");
            // The PNGs show log(1 + n) / log(1 + most) as the grey level itself (no sRGB
            // curve), with one `most` for all of an object's densities: per-map scales
            // drew k = 1 and k = 8 alike. ±1 level covers the f32 rounding at a level's edge.
            for (obj, maps) in &drawn {
                let most = maps
                    .iter()
                    .flat_map(|(img, _)| img.pixels.iter().map(|p| p[0]))
                    .fold(0.0f32, f32::max);
                let mut brightest = 0;
                for (img, png) in maps {
                    let (w, h, grey) = common::read_png(png);
                    assert_eq!((w as usize, h as usize), (img.width, img.height));
                    let half = (img.width - 2) / 2;
                    for (i, p) in img.pixels.iter().enumerate() {
                        // The gap between the halves is red, apart from every grey level.
                        if (half..half + 2).contains(&(i % img.width)) {
                            assert_eq!(&grey[3 * i..3 * i + 3], &[255, 0, 0], "{}", png.display());
                            continue;
                        }
                        let want = 255.0 * (1.0 + p[0]).ln() / (1.0 + most).ln();
                        let got = grey[3 * i];
                        assert!(
                            (got as f32 - want).abs() <= 1.0,
                            "{}: pixel {i} grey {got}, want {want} ({} a path of {most} on {obj})",
                            png.display(),
                            p[0]
                        );
                        brightest = brightest.max(got);
                    }
                }
                assert_eq!(brightest, 255, "{obj}: its busiest pixel is white");
            }
        }
        let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
        if name == "teaser_no_nee" || name == "teaser" {
            let off = report.contains("Next-event estimation off");
            assert_eq!(off, name == "teaser_no_nee", "{report}");
        }
        // A table with the bias bound says when the bound is left unresolved (its cell
        // reads "not resolved"), whichever experiment wrote it.
        if report.contains("bias_upper95") {
            assert!(
                report.contains("not resolved where fewer than 30 object pixels carry a term"),
                "{}: {report}",
                cfg.display()
            );
        }
        let mut images = 0;
        for part in report.split("](").skip(1) {
            let file = &part[..part.find(')').unwrap()];
            if file.ends_with(".png") {
                check_png(&dir.join(file));
                images += 1;
            }
        }
        assert!(images > 0, "{}: the report embeds no plot", cfg.display());
    }
    // The teaser's renders carry their pair's seeds, so `merge` knows a copy by its seed
    // (it compared pixels only before); its montages are no renders and are refused.
    let teaser = tmp.path().join("teaser-quick");
    std::fs::copy(teaser.join("pt_k1.exr"), teaser.join("copy.exr")).unwrap();
    let merge = |inputs: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .arg("merge")
            .args(inputs.iter().map(|i| teaser.join(i)))
            .arg("--out")
            .arg(tmp.path().join("merged"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = merge(&["pt_k1.exr", "copy.exr"]);
    assert!(err.contains("shares seed 11 with"), "{err}");
    let err = merge(&["pt_k1.exr", "teaser_k1.exr"]);
    assert!(err.contains("teaser_k1.exr: no stcvae render tag"), "{err}");
}

/// The shipped sphere scene, by absolute path (configs written to temporary folders name it).
const SPHERE_SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../configs/scenes/sphere.toml"
);

/// A teaser of the sphere at `densities` (a TOML list's items), 8 × 8 at 2 spp in both
/// budgets, written to `cfg`.
fn write_tiny_teaser(cfg: &Path, densities: &str) {
    let scene = SPHERE_SCENE;
    std::fs::write(
        cfg,
        format!(
            "kind = \"teaser\"\ntitle = \"t\"\nscene = {scene:?}\ndensities = [{densities}]\n\
             [full]\nsize = 8\nspp = 2\n[quick]\nsize = 8\nspp = 2\n"
        ),
    )
    .unwrap();
}

/// The note of files an earlier run left names 12 of them, sorted, and counts the rest;
/// hidden files, folders and links are not counted (13 plain files, a hidden one, a folder
/// and a link left in the folder of an 8 × 8 teaser at 2 spp).
#[test]
fn the_left_over_note_names_twelve_sorted_files_and_counts_the_rest() {
    let d = tempfile::tempdir().unwrap();
    let cfg = d.path().join("tiny.toml");
    write_tiny_teaser(&cfg, "1.0");
    let out = d.path().join("results");
    let folder = out.join("tiny-quick");
    std::fs::create_dir_all(folder.join("a_dir")).unwrap();
    // Neither creation order nor its reverse is sorted (tmpfs lists the newest first).
    for i in [7, 2, 12, 0, 9, 4, 11, 1, 6, 10, 3, 8, 5] {
        std::fs::write(folder.join(format!("u{i:02}.txt")), "x").unwrap();
    }
    std::fs::write(folder.join(".hidden"), "x").unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink("u00.txt", folder.join("a_link")).unwrap();
    let o = quick_experiment(&cfg, &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let names: Vec<String> = (0..12).map(|i| format!("u{i:02}.txt")).collect();
    let want = format!(
        "13 files of an earlier run that this one did not write (not in its report.md): {} \
         and 1 more; delete",
        names.join(", ")
    );
    assert!(err.contains(&want), "{err}");
}

/// A second run into the same folder with fewer densities names the first run's images
/// it did not write again (they stayed beside the new report unsaid), and deletes none;
/// a run that rewrites them all says nothing.
#[test]
fn files_of_an_earlier_run_are_named() {
    let d = tempfile::tempdir().unwrap();
    let scene = SPHERE_SCENE;
    let cfg = d.path().join("tiny.toml");
    let write = |densities: &str| write_tiny_teaser(&cfg, densities);
    let out = d.path().join("results");
    let run = || {
        let o = quick_experiment(&cfg, &out);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{err}");
        err
    };
    write("1.0, 2.0");
    assert!(!run().contains("earlier run"));
    assert!(!run().contains("earlier run"), "all rewritten");
    write("1.0");
    let err = run();
    let note = err
        .lines()
        .find(|l| l.contains("of an earlier run that this one did not write"))
        .unwrap_or_else(|| panic!("no note in {err}"));
    let files = note.split("): ").nth(1).unwrap();
    assert!(
        files.contains("pt_k2.exr")
            && files.contains("teaser_k2.png")
            && !files.contains("k1")
            && !files.contains("report.md")
            && !files.contains("figures.csv"),
        "{note}"
    );
    assert!(
        out.join("tiny-quick").join("pt_k2.exr").exists(),
        "named, not deleted"
    );
    // A scene whose camera looks away from the object has nothing to measure: an error
    // naming it, not offsets of 0/0 in figures.csv.
    let away = d.path().join("away.toml");
    std::fs::write(
        &away,
        std::fs::read_to_string(scene)
            .unwrap()
            .replace("target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 10.0]"),
    )
    .unwrap();
    std::fs::write(
        &cfg,
        format!(
            "kind = \"absorption\"\ntitle = \"t\"\nscene = {away:?}\nabsorptions = [0.01]\n\
             [full]\nsize = 8\nspp = 2\n[quick]\nsize = 8\nspp = 2\n"
        ),
    )
    .unwrap();
    let o = quick_experiment(&cfg, &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.contains("away.toml: no pixel differs between the renders")
            && err.contains("out of view, unlit or black"),
        "{err}"
    );
}

#[test]
fn bad_experiment_config_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("bad.toml");
    // The config with `densities` and `full.spp` as given: its error (stderr) and success.
    let run = |densities: &str, spp: &str| {
        std::fs::write(
            &cfg,
            format!(
                "kind = \"teaser\"\ntitle = \"t\"\nscene = \"x.toml\"\ndensities = [{densities}]\n\
                 [full]\nsize = 8\nspp = {spp}\n[quick]\nsize = 8\nspp = 2\n"
            ),
        )
        .unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .args(["experiment", cfg.to_str().unwrap(), "--quick"])
            .output()
            .unwrap();
        (
            String::from_utf8_lossy(&out.stderr).into_owned(),
            out.status.success(),
        )
    };
    let (err, success) = run("-1.0", "2");
    assert!(!success);
    assert!(
        err.contains("bad.toml") && err.contains("densities"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    // A value the field's type cannot hold names the field's range, not the type's
    // ("expected a whole number in [0, 4294967295]" for spp = 1e9 or size = -5).
    let (err, success) = run("1.0", "1e9");
    assert!(
        !success && err.contains("expected a whole number in [2, 1073741824]"),
        "{err}"
    );
    let (err, success) = run("1.0", "-2");
    assert!(
        !success && err.contains("expected a whole number in [2, 1073741824]"),
        "{err}"
    );
    // spp near u32::MAX: a pair's halves added up in u32 and wrapped to 2 in the tag.
    let (err, success) = run("1.0", "4294967295");
    assert!(
        !success && err.contains("full.spp = 4294967295 is out of range"),
        "{err}"
    );
    // A fallback threshold above the model's range (no max_tau in the scene) fails before
    // any render, not after PT's pair and the thresholds before it.
    let scene = SPHERE_SCENE;
    // A fallback experiment of `scene` at the given thresholds, written to `cfg`.
    let fallback = |scene: &std::path::Path, thresholds: &str| {
        std::fs::write(
            &cfg,
            format!(
                "kind = \"fallback\"\ntitle = \"t\"\nscene = {scene:?}\ndensities = [1.0]\n\
                 thresholds = [{thresholds}]\n[full]\nsize = 8\nspp = 2\n[quick]\nsize = 8\n\
                 spp = 2\n"
            ),
        )
        .unwrap();
    };
    fallback(std::path::Path::new(scene), "0.0, 400.0");
    let d = tempfile::tempdir().unwrap();
    let out = quick_experiment(&cfg, d.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && err.contains("threshold 400 is above the model's training maximum"),
        "{err}"
    );
    assert!(
        std::fs::read_dir(d.path()).unwrap().next().is_none(),
        "a folder or file was made before the error"
    );
    // The same with the scene's own max_tau in a scene file of `pt`: the thresholds are
    // checked as the ST-CVAE renders they are for, before PT's pair.
    let pt_scene = d.path().join("capped.toml");
    std::fs::write(
        &pt_scene,
        std::fs::read_to_string(scene).unwrap() + "max_tau = 50.0\n",
    )
    .unwrap();
    fallback(&pt_scene, "0.0, 60.0");
    let out_dir = tempfile::tempdir().unwrap();
    let out = quick_experiment(&cfg, out_dir.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("threshold 60") && err.contains("max_tau = 50"),
        "{err}"
    );
    assert!(
        std::fs::read_dir(out_dir.path()).unwrap().next().is_none(),
        "a folder or file was made before the error"
    );
    // An empty scene name is named as such: joined to the config's folder it read as
    // that folder ("cannot read scene file: Is a directory").
    fallback(std::path::Path::new(""), "0.0");
    let err = String::from_utf8_lossy(&quick_experiment(&cfg, out_dir.path()).stderr).into_owned();
    assert!(
        err.contains("bad.toml: scene = \"\" names no file"),
        "{err}"
    );
    // A scene or a training config given instead says what it is, not "unknown field".
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs");
    for (file, what) in [
        ("scenes/sphere.toml", "a scene file"),
        ("train/default.toml", "not an experiment config"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .args(["experiment", &format!("{root}/{file}")])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert!(err.contains(file) && err.contains(what), "{err}");
    }
}

/// Mistakes that used to surface only after rendering (a missing mesh in the second
/// scene) or never (a density listed twice overwrote its images; a wrong type named no
/// field) are refused before any work, naming the file and the field or line, and leave
/// no output folder.
#[test]
fn experiment_configs_are_checked_before_any_rendering() {
    let tmp = tempfile::tempdir().unwrap();
    let scenes = root().join("configs/scenes");
    let bunny = std::fs::read_to_string(scenes.join("bunny.toml"))
        .unwrap()
        .replace("../../assets", &root().join("assets").display().to_string());
    std::fs::write(tmp.path().join("ok.toml"), &bunny).unwrap();
    std::fs::write(
        tmp.path().join("broken.toml"),
        bunny.replace("bunny.glb", "no-such-mesh.glb"),
    )
    .unwrap();
    let run_kind = |kind: &str, body: &str| {
        let cfg = tmp.path().join("exp.toml");
        std::fs::write(
            &cfg,
            format!(
                "kind = \"{kind}\"\ntitle = \"t\"\n{body}\n\
                 [full]\nsize = 8\nspp = 2\n[quick]\nsize = 8\nspp = 2\n"
            ),
        )
        .unwrap();
        let out = quick_experiment(&cfg, &tmp.path().join("results"));
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!err.contains("panicked"), "{err}");
        assert!(!tmp.path().join("results/exp-quick").exists(), "{err}");
        err
    };
    let run = |body: &str| run_kind("complexity", body);
    let e = run("scene = \"ok.toml\"\nscenes = [\"broken.toml\"]\ndensities = [1.0]");
    assert!(e.contains("no-such-mesh.glb"), "{e}");
    let e = run("scene = \"ok.toml\"\ndensities = [1.0, 2.0, 1.0]");
    assert!(e.contains("densities") && e.contains("twice"), "{e}");
    let e = run("scene = \"ok.toml\"\ndensities = \"1.0\"");
    assert!(e.contains("exp.toml:4") && e.contains("densities"), "{e}");
    // An empty list is refused as such, not as a mismatch with `paper`; in a fallback
    // config, whose densities default to [1], it read as no key at all, and the run
    // rendered at density 1 under a description of another.
    for (kind, other) in [
        ("teaser", "paper = [2.2]"),
        ("fallback", "thresholds = [0.0]"),
    ] {
        let e = run_kind(
            kind,
            &format!("scene = \"ok.toml\"\ndensities = []\n{other}"),
        );
        assert!(
            e.contains("densities") && e.contains("an empty list: give at least one value"),
            "{kind}: {e}"
        );
    }
    // Densities as `bench render --k` takes them; the paper's figures positive.
    let e = run_kind(
        "absorption",
        "scene = \"ok.toml\"\nabsorptions = [1e-300, 0.5]",
    );
    assert!(
        e.contains("absorptions: 1e-300 is out of range: allowed [1e-6, 1)"),
        "{e}"
    );
    // Within the config's range but too dense for this object's surface offset: refused
    // before the renders at the densities before it, naming the density and the most that
    // fits (the bunny's densest channel, 187.5, at the 48,741 its size allows).
    let e = run("scene = \"ok.toml\"\ndensities = [1.0, 1000.0]");
    assert!(
        e.contains("ok.toml: densities = 1000: medium.sigma_t[0] = 150000 is too dense")
            && e.contains("(densities up to 259.9 fit this object)"),
        "{e}"
    );
    // A kind that scales no density checks the scene's own medium, without the hint.
    std::fs::write(
        tmp.path().join("dense.toml"),
        bunny.replace(
            "sigma_t = [150.0, 187.5, 125.0]",
            "sigma_t = [150000.0, 187.5, 125.0]",
        ),
    )
    .unwrap();
    let e = run_kind("absorption", "scene = \"dense.toml\"\nabsorptions = [0.5]");
    assert!(
        e.contains("dense.toml: medium.sigma_t[0] = 150000 is too dense")
            && !e.contains("densities up to"),
        "{e}"
    );
    let e = run("scene = \"ok.toml\"\ndensities = [1e-300]");
    assert!(
        e.contains("densities: 1e-300 is out of range: allowed [0.001, 1000]"),
        "{e}"
    );
    let e = run_kind(
        "teaser",
        "scene = \"ok.toml\"\ndensities = [1.0]\npaper = [nan]",
    );
    assert!(e.contains("paper must be positive and finite"), "{e}");
    // A field of another kind would be ignored: refused, naming it.
    let e = run("scene = \"ok.toml\"\ndensities = [1.0]\nthresholds = [1.0]");
    assert!(
        e.contains("exp.toml") && e.contains("thresholds does not apply to kind = \"complexity\""),
        "{e}"
    );
    // So would a budget's size and spp where the kind renders nothing or renders for a
    // time, and a kind that renders needs them.
    let e = run_kind("distributions", "");
    assert!(
        e.contains("full.size does not apply to kind = \"distributions\", which renders no image"),
        "{e}"
    );
    let e = run_kind("nee", "scene = \"ok.toml\"");
    assert!(
        e.contains("full.spp does not apply to kind = \"nee\", which renders for `seconds`"),
        "{e}"
    );
    // Without NEE a delta light is never reached: every light of ok.toml (the default
    // bunny) is one, so the renders would be lit by the environment alone.
    let e = run("scene = \"ok.toml\"\ndensities = [1.0]\nnee = false");
    assert!(
        e.contains("ok.toml: every light is a delta light") && e.contains("(nee = false)"),
        "{e}"
    );
    let cfg = tmp.path().join("exp.toml");
    std::fs::write(
        &cfg,
        "kind = \"nee\"\ntitle = \"t\"\nscene = \"ok.toml\"\n[full]\nsize = 8\nseconds = 1.0\n\
         reference_spp = 4\n[quick]\nsize = 8\nseconds = 1.0\nreference_spp = 4\n",
    )
    .unwrap();
    let out = quick_experiment(&cfg, &tmp.path().join("results"));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && e.contains("the \"PT, no NEE\" row"),
        "{e}"
    );
    // quality replaces the lights by a delta light and renders with NEE: `nee` refused.
    let e = run_kind(
        "quality",
        "scene = \"ok.toml\"\ndensities = [1.0]\nnee = false",
    );
    assert!(
        e.contains("nee does not apply to kind = \"quality\""),
        "{e}"
    );
    // The size is the width; the camera's aspect sets the height, bounded as the width (a
    // 128×8 camera at size 8 would render 8×1).
    std::fs::write(
        tmp.path().join("wide.toml"),
        bunny.replace("height = 128", "height = 8"),
    )
    .unwrap();
    let e = run("scene = \"wide.toml\"\ndensities = [1.0]");
    assert!(
        e.contains("wide.toml: its camera's aspect (128 x 8) makes full.size = 8 a 8 x 1 image"),
        "{e}"
    );
    let cfg = tmp.path().join("exp.toml");
    std::fs::write(
        &cfg,
        "kind = \"quality\"\ntitle = \"t\"\nscene = \"ok.toml\"\ndensities = [1.0]\n\
         [full]\nsize = 8\n[quick]\nsize = 8\nspp = 2\n",
    )
    .unwrap();
    let out = quick_experiment(&cfg, &tmp.path().join("results"));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && e.contains("[full] needs spp: kind = \"quality\" renders with it"),
        "{e}"
    );
}

/// The full teaser experiment into `out`, on the CPU, from the repository root, its
/// stderr piped: it renders for minutes.
fn full_teaser(out: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args([
            "experiment",
            "configs/experiments/teaser.toml",
            "--device",
            "cpu",
            "--out",
        ])
        .arg(out)
        .current_dir(root())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// Ctrl-C (SIGINT) during an experiment stops it after the current render pass: exit status
/// 130, a one-line message, no report (a cut-short render must not be measured) and no
/// empty folders.
#[cfg(unix)]
#[test]
fn an_interrupted_experiment_writes_no_report() {
    use std::time::Duration;
    let d = tempfile::tempdir().unwrap();
    let child = full_teaser(&d.path().join("fresh"));
    // The full teaser renders for minutes: interrupted two seconds after it has started.
    let out = d.path().join("fresh/teaser");
    common::interrupt_when(
        &child,
        || out.exists(),
        Duration::from_secs(2),
        1,
        "the experiment",
    );
    let done = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    assert_eq!(done.status.code(), Some(130), "{err}");
    assert!(err.contains("interrupted: no report written"), "{err}");
    assert!(!out.join("report.md").exists());
    // Its first render was cut short, so nothing was saved: the folders the run made, the
    // results root among them, are gone again.
    assert!(!d.path().join("fresh").exists(), "{err}");

    // Over an earlier run's results, stopped before it saved anything: the earlier report
    // and figures stay as they were (they were removed up front).
    let out = d.path().join("earlier/teaser");
    std::fs::create_dir_all(&out).unwrap();
    for f in ["report.md", "figures.csv"] {
        std::fs::write(out.join(f), "earlier").unwrap();
    }
    let mut child = full_teaser(&d.path().join("earlier"));
    // Nothing shows in the folder when it starts: its first line on stderr ("experiment
    // teaser … ->", written as Ctrl-C's handler goes in) does. Two seconds on, it is
    // mid-render (the first render takes minutes).
    let seen = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let reader = {
        let (seen, pipe) = (seen.clone(), child.stderr.take().unwrap());
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::BufReader::new(pipe).lines().map_while(Result::ok) {
                let mut s = seen.lock().unwrap();
                s.push_str(&line);
                s.push('\n');
            }
        })
    };
    let started = || seen.lock().unwrap().contains("experiment teaser");
    common::interrupt_when(&child, started, Duration::from_secs(2), 1, "the rerun");
    let status = child.wait().unwrap();
    reader.join().unwrap();
    let err = seen.lock().unwrap().clone();
    assert_eq!(status.code(), Some(130), "{err}");
    assert!(err.contains("the earlier run's report"), "{err}");
    for f in ["report.md", "figures.csv"] {
        assert_eq!(
            std::fs::read_to_string(out.join(f)).unwrap(),
            "earlier",
            "{f}: {err}"
        );
    }
}

/// A rerun whose first image cannot be saved (its name taken by a folder; a full disk
/// alike) fails having saved nothing, and leaves the earlier run's report and figures as
/// they were: they went only once a file of the new run was in place (removed before the
/// first save, a failed one took them).
#[test]
fn a_rerun_that_saves_nothing_keeps_the_earlier_report() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("teaser-quick");
    std::fs::create_dir_all(out.join("pt_k1.exr")).unwrap();
    for f in ["report.md", "figures.csv"] {
        std::fs::write(out.join(f), "earlier").unwrap();
    }
    let done = Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args([
            "experiment",
            "configs/experiments/teaser.toml",
            "--quick",
            "--device",
            "cpu",
            "--out",
        ])
        .arg(d.path())
        .current_dir(root())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    assert!(!done.status.success(), "{err}");
    assert!(
        err.contains("pt_k1.exr") && err.contains("nothing was saved: the earlier run's report"),
        "{err}"
    );
    for f in ["report.md", "figures.csv"] {
        assert_eq!(
            std::fs::read_to_string(out.join(f)).unwrap(),
            "earlier",
            "{f}: {err}"
        );
    }
}

/// The cells of one CSV line, quoted cells (RFC 4180: "" is a quote) unquoted.
fn csv_cells(line: &str) -> Vec<String> {
    let (mut cells, mut cell, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cell.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => cells.push(std::mem::take(&mut cell)),
            (c, _) => cell.push(c),
        }
    }
    cells.push(cell);
    cells
}

/// `stcvae experiment configs/experiments/nee.toml --quick --device DEVICE`, plus `extra`,
/// into `out` (on Vulkan alone where the device is a GPU).
fn quick_nee(device: &str, extra: &[&std::ffi::OsStr], out: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args([
            "experiment",
            "configs/experiments/nee.toml",
            "--quick",
            "--device",
            device,
        ])
        .args(extra)
        .arg("--out")
        .arg(out)
        .env("WGPU_BACKEND", "vulkan")
        .current_dir(root())
        .output()
        .unwrap()
}

/// An experiment on the GPU (lavapipe in CI): the equal-time comparison renders every
/// method to its budgets there, with finite figures, and the report names the device.
/// Skipped, with the reason, only where no Vulkan adapter exists and not under CI.
#[test]
fn an_experiment_runs_on_the_gpu() {
    let tmp = tempfile::tempdir().unwrap();
    let out = quick_nee("gpu", &[], tmp.path());
    if common::skipped_without_vulkan(&out, "an_experiment_runs_on_the_gpu") {
        return;
    }
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let dir = tmp.path().join("nee-quick");
    let csv = std::fs::read_to_string(dir.join("figures.csv")).unwrap();
    let mut lines = csv.lines();
    let header = csv_cells(lines.next().unwrap());
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (spp, seconds) = (column("spp"), column("seconds"));
    let mut rows = 0;
    for line in lines {
        let cells = csv_cells(line);
        for c in &cells {
            if let Ok(v) = c.parse::<f64>() {
                assert!(v.is_finite(), "{line}");
            }
        }
        let (s, t): (f64, f64) = (cells[spp].parse().unwrap(), cells[seconds].parse().unwrap());
        assert!(s >= 1.0 && t > 0.0, "{line}");
        rows += 1;
    }
    // Three methods at three budgets each.
    assert_eq!(rows, 9, "{csv}");
    let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(report.contains("gpu: "), "{report}");
}

/// A scene with more lights than the GPU kernels take is refused on the GPU before any
/// render, by the scene's name and the limit, and the run makes no folder (it failed at its
/// first render, after the renders of the scenes before it).
#[test]
fn an_experiment_on_the_gpu_refuses_too_many_lights_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let scenes = root().join("configs/scenes");
    let light = "\n[[light]]\nkind = \"directional\"\ndirection = [0.5, -0.5, -1.0]\n\
                 irradiance = [0.5, 0.5, 0.5]\nangular_diameter_deg = 10.0\n";
    let scene = std::fs::read_to_string(scenes.join("bunny_sun.toml"))
        .unwrap()
        .replace(
            "../../assets/bunny.glb",
            &root().join("assets/bunny.glb").to_string_lossy(),
        )
        + &light.repeat(64);
    std::fs::write(tmp.path().join("many_lights.toml"), scene).unwrap();
    let config = std::fs::read_to_string(root().join("configs/experiments/nee.toml"))
        .unwrap()
        .replace("../scenes/bunny_sun.toml", "many_lights.toml");
    std::fs::write(tmp.path().join("nee.toml"), config).unwrap();
    let results = tmp.path().join("results");
    let out = Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args([
            "experiment",
            "nee.toml",
            "--quick",
            "--device",
            "gpu",
            "--out",
        ])
        .arg(&results)
        .env("WGPU_BACKEND", "vulkan")
        .current_dir(tmp.path())
        .output()
        .unwrap();
    if common::skipped_without_vulkan(&out, "an_experiment_on_the_gpu_refuses_too_many_lights") {
        return;
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("many_lights.toml: 65 lights; the GPU kernels take at most 64"),
        "{err}"
    );
    assert!(!results.exists(), "{err}");
}

/// A model in the output folder under a name the run writes is refused before any render
/// and stays: `--model` at OUT/nee-quick/figures.csv was removed as the previous run's
/// figures, and the run failed at its next render.
#[test]
fn an_experiment_never_removes_its_model() {
    let tmp = tempfile::tempdir().unwrap();
    let folder = tmp.path().join("nee-quick");
    std::fs::create_dir(&folder).unwrap();
    let shipped = std::fs::read(root().join("models/default.stcvae")).unwrap();
    let model = folder.join("figures.csv");
    std::fs::write(&model, &shipped).unwrap();
    let out = quick_nee("cpu", &["--model".as_ref(), model.as_os_str()], tmp.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("figures.csv is in the output folder") && !err.contains("panicked"),
        "{err}"
    );
    assert_eq!(std::fs::read(&model).unwrap(), shipped);
}
