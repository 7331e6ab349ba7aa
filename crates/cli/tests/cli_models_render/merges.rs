//! `render`'s image set and `merge` of renders: averaged by spp, the preview's exposure,
//! wide images, an interrupted merge, and renders of both devices merged as one scene's.

use super::*;

/// The merged preview is at the exposure the inputs were rendered with (their reports
/// record it), or at `--exposure`; before, it was always at 1, four times darker than
/// either input of two `--exposure 4` renders. The EXR is linear whatever the exposure.
#[test]
fn a_merged_preview_keeps_the_inputs_exposure() {
    use render_gpu::image_io::{encode_png, read_exr};
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 16);
    let (a, b) = (d.path().join("a"), d.path().join("b"));
    for (out, seed) in [(&a, "1"), (&b, "2")] {
        ok(&render_scene(
            &scene,
            "pt",
            "2",
            seed,
            out,
            &["--exposure", "4"],
        ));
    }
    let m = d.path().join("m");
    ok(&merge_renders(&a, &b, &m));
    let (img, _) = read_exr(&m.with_extension("exr")).unwrap();
    let png = |p: &Path| std::fs::read(p.with_extension("png")).unwrap();
    assert_eq!(png(&m), encode_png(&img, 4.0).unwrap());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(m.with_extension("json")).unwrap()).unwrap();
    assert_eq!(report["exposure"], 4.0);
    // Given: it wins.
    let m2 = d.path().join("m2");
    ok(&stcvae(&[
        "merge",
        a.with_extension("exr").to_str().unwrap(),
        b.with_extension("exr").to_str().unwrap(),
        "--out",
        m2.to_str().unwrap(),
        "--exposure",
        "0.5",
    ]));
    assert_eq!(png(&m2), encode_png(&img, 0.5).unwrap());
    // Inputs that disagree (a merge at 4 and a render at 1): exposure 1, said so.
    let c = d.path().join("c");
    ok(&render_scene(&scene, "pt", "2", "3", &c, &[]));
    let o = stcvae(&[
        "merge",
        m.with_extension("exr").to_str().unwrap(),
        c.with_extension("exr").to_str().unwrap(),
        "--out",
        d.path().join("m3").to_str().unwrap(),
    ]);
    let err = ok(&o);
    assert!(err.contains("not all at one recorded exposure"), "{err}");
    let (img3, _) = read_exr(&d.path().join("m3.exr")).unwrap();
    assert_eq!(png(&d.path().join("m3")), encode_png(&img3, 1.0).unwrap());
    // An edited report whose exposure is none (−5): named, taken as none, so the merge of
    // it with a render at 4 is at exposure 1.
    let json = b.with_extension("json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["exposure"] = serde_json::json!(-5.0);
    std::fs::write(&json, v.to_string()).unwrap();
    let m4 = d.path().join("m4");
    let err = ok(&merge_renders(&a, &b, &m4));
    assert!(
        err.contains(&format!(
            "{}: exposure = -5.0 is not a preview exposure",
            json.display()
        )),
        "{err}"
    );
    assert_eq!(png(&m4), encode_png(&img, 1.0).unwrap());
    // Datasets have no preview.
    let e = fails(&stcvae(&[
        "merge",
        "x.bin",
        "--out",
        "y.bin",
        "--exposure",
        "2",
    ]));
    assert!(
        e.contains("--exposure applies to renders (.exr) only"),
        "{e}"
    );
}

/// Ctrl-C during an image merge leaves the set whole or not at all, with exit status 130:
/// "nothing written" and no output (stopped while reading the inputs), or "written whole"
/// with all three files readable (stopped while writing: the set is finished), and never a
/// hidden temporary. Before, the merge had no handler: the signal ended it wherever it was, up
/// to between two renames of the set. The signal goes out once the handler is in place
/// (/proc's caught-signal mask), so the test does not race its installation; when the
/// inputs are read decides only which of the two clean outcomes it sees.
#[cfg(target_os = "linux")]
#[test]
fn an_interrupted_image_merge_writes_the_set_whole_or_not_at_all() {
    use render_gpu::image_io::{RenderTag, RgbImage, read_exr, write_exr};
    let d = tempfile::tempdir().unwrap();
    // 1,024² renders of varied values: reading and writing them takes a while.
    let mut img = RgbImage::new(1024, 1024);
    let mut x = 1u32;
    for p in &mut img.pixels {
        for v in p.iter_mut() {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            *v = (x >> 8) as f32 / (1u32 << 24) as f32;
        }
    }
    let mut inputs = Vec::new();
    for seed in 1..=4u64 {
        let path = d.path().join(format!("r{seed}.exr"));
        let tag = RenderTag {
            spp: 4,
            scene_hash: 7,
            seeds: vec![seed],
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        };
        write_exr(&path, &img, &tag).unwrap();
        inputs.push(path);
    }
    let out = d.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .arg("merge")
        .args(&inputs)
        .args(["--out", "out/m"])
        .current_dir(d.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    assert!(
        common::wait_for_sigint_handler(&child),
        "merge ended without ever handling Ctrl-C"
    );
    // SAFETY: a plain system call on a child this test owns and has not reaped.
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) },
        0
    );
    let o = child.wait_with_output().unwrap();
    let err = common::stderr(&o);
    let mut left: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    // None: killed by the signal.
    assert_eq!(o.status.code(), Some(130), "{err}");
    if err.contains("interrupted while writing: the merged set was written whole") {
        assert_eq!(left, ["m.exr", "m.json", "m.png"], "{err}");
        let (merged, tag) = read_exr(&out.join("m.exr")).unwrap();
        assert_eq!(tag.unwrap().spp, 16);
        assert_eq!(merged.pixels.len(), img.pixels.len());
    } else {
        assert!(
            err.contains("interrupted: nothing written to out/m.{exr,png,json}"),
            "{err}"
        );
        assert!(left.is_empty(), "{left:?}");
    }
}

/// A merge of images wider than tall (every other merge test's are square): the merged
/// image and its report keep width and height apart, and each pixel is the spp-weighted
/// mean of the inputs', (1·a + 3·b)/4.
#[test]
fn a_merge_of_wide_images_keeps_their_shape() {
    use render_gpu::image_io::{RenderTag, RgbImage, read_exr, write_exr};
    let d = tempfile::tempdir().unwrap();
    for (seed, spp, value) in [(1u64, 1u64, 1.0f32), (2, 3, 2.0)] {
        let mut img = RgbImage::new(4, 2);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = [value * (i + 1) as f32, value, 0.5 * value];
        }
        let tag = RenderTag {
            spp,
            scene_hash: 7,
            seeds: vec![seed],
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        };
        write_exr(&d.path().join(format!("r{seed}.exr")), &img, &tag).unwrap();
    }
    let o = common::stcvae(&["merge", "r1.exr", "r2.exr", "--out", "m"], d.path());
    assert!(o.status.success(), "{}", common::stderr(&o));
    let (merged, tag) = read_exr(&d.path().join("m.exr")).unwrap();
    assert_eq!((merged.width, merged.height, tag.unwrap().spp), (4, 2, 4));
    for (i, p) in merged.pixels.iter().enumerate() {
        let want = [1.75 * (i + 1) as f32, 1.75, 0.875];
        for (c, (&got, want)) in p.iter().zip(want).enumerate() {
            assert!(
                (got - want).abs() <= 1e-6 * want,
                "pixel {i}, channel {c}: {got}"
            );
        }
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("m.json")).unwrap()).unwrap();
    assert_eq!(
        (&json["width"], &json["height"]),
        (&4.into(), &2.into()),
        "{json}"
    );
}

#[test]
fn render_writes_exr_png_json_and_merge_averages_by_spp() {
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 16);
    let a = d.path().join("a");
    let b = d.path().join("b");
    for (out, seed, spp) in [(&a, "1", "4"), (&b, "2", "8")] {
        ok(&render_scene(&scene, "stcvae", spp, seed, out, &[]));
    }
    for ext in ["exr", "png", "json"] {
        assert!(a.with_extension(ext).exists(), "missing .{ext}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a.with_extension("json")).unwrap()).unwrap();
    assert_eq!(json["spp"], 4);
    assert!(json["mean_sphere_steps_per_path"].as_f64().unwrap() > 0.0);
    // The rates are the counters' own: paths over seconds, steps and events over paths
    // (16² pixels × 4 spp, one path each).
    let stat = |k: &str| json["stats"][k].as_f64().unwrap();
    let field = |k: &str| json[k].as_f64().unwrap();
    assert_eq!(stat("paths"), 1024.0, "{json}");
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs();
    assert!(
        close(field("paths_per_second"), 1024.0 / field("seconds")),
        "{json}"
    );
    assert!(
        close(field("mean_sphere_steps_per_path"), stat("steps") / 1024.0),
        "{json}"
    );
    assert!(
        close(field("mean_pt_events_per_path"), stat("events") / 1024.0),
        "{json}"
    );
    // A CPU device names the CPU's model where the OS reports one (timings depend on it;
    // `auto` renders on a hardware GPU where there is one).
    let device = json["device"].as_str().unwrap();
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = info
        .lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, m)| m.split_whitespace().collect::<Vec<_>>().join(" "));
    if device.starts_with("cpu")
        && let Some(model) = model.filter(|m| !m.is_empty())
    {
        assert!(device.contains(&model), "{device} lacks {model}");
    }
    // The dispatch record is the GPU's (one band at 16² in one row of workgroups, at least
    // one dispatch), null on the CPU.
    let dispatch = &json["gpu_dispatch"];
    if device.starts_with("cpu") {
        assert!(dispatch.is_null(), "{dispatch}");
    } else {
        assert_eq!(
            (&dispatch["bands"], &dispatch["grid_rows"]),
            (&1.into(), &1.into()),
            "{dispatch}"
        );
        assert!(dispatch["dispatches"].as_u64().unwrap() >= 1, "{dispatch}");
    }
    let m = d.path().join("m");
    // With their own reports: no warning, and the renders' integrator is the merge's.
    let err = ok(&merge_renders(&a, &b, &m));
    assert!(!err.contains("warning"), "{err}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(m.with_extension("json")).unwrap()).unwrap();
    assert_eq!(json["integrator"], "stcvae", "{json}");
    assert_eq!(json["renders_complete"], true, "{json}");
    let (ia, _) = render_gpu::image_io::read_exr(&a.with_extension("exr")).unwrap();
    let (ib, _) = render_gpu::image_io::read_exr(&b.with_extension("exr")).unwrap();
    let (im, tag) = render_gpu::image_io::read_exr(&m.with_extension("exr")).unwrap();
    let tag = tag.unwrap();
    assert_eq!(tag.spp, 12);
    // The merge keeps the inputs' view, in its tag and its report.
    let a_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a.with_extension("json")).unwrap()).unwrap();
    let view = tag
        .view_hash
        .expect("the merge of two new renders keeps their view");
    assert_eq!(json["view_hash"], format!("{view:016x}"), "{json}");
    assert_eq!(json["view_hash"], a_json["view_hash"], "{json}");
    for i in 0..im.pixels.len() {
        for c in 0..3 {
            let want = (4.0 * ia.pixels[i][c] + 8.0 * ib.pixels[i][c]) / 12.0;
            assert!((im.pixels[i][c] - want).abs() <= 1e-5 * want.abs().max(1.0));
        }
    }
    // A different scene (another σ_t, all else as `a` but the seed) is refused.
    let other = d.path().join("o.toml");
    std::fs::write(
        &other,
        std::fs::read_to_string(&scene).unwrap().replace(
            "sigma_t = [20.0, 20.0, 20.0]",
            "sigma_t = [30.0, 20.0, 20.0]",
        ),
    )
    .unwrap();
    let o = d.path().join("o");
    ok(&render_scene(&other, "stcvae", "1", "3", &o, &[]));
    let e = fails(&stcvae(&[
        "merge",
        a.with_extension("exr").to_str().unwrap(),
        o.with_extension("exr").to_str().unwrap(),
        "--out",
        d.path().join("x").to_str().unwrap(),
    ]));
    assert!(e.contains("different scenes"), "{e}");
    // A render's preview given instead of its EXR: named, with the file to give.
    let e = fails(&stcvae(&[
        "merge",
        a.with_extension("png").to_str().unwrap(),
        o.with_extension("exr").to_str().unwrap(),
        "--out",
        d.path().join("x").to_str().unwrap(),
    ]));
    assert!(
        e.contains("a.png: merge reads a render's .exr") && e.contains("a.exr"),
        "{e}"
    );
    // The same render given twice (spelt two ways) would count twice: refused.
    let a_exr = a.with_extension("exr");
    let a_dot = d.path().join(".").join("a.exr");
    let e = fails(&stcvae(&[
        "merge",
        a_exr.to_str().unwrap(),
        a_dot.to_str().unwrap(),
        "--out",
        d.path().join("x").to_str().unwrap(),
    ]));
    assert!(e.contains("same file"), "{e}");
    // `--out a` writes a.exr: it would overwrite the input, so it is refused and the
    // input is untouched.
    let before = std::fs::read(&a_exr).unwrap();
    let e = fails(&stcvae(&[
        "merge",
        a_exr.to_str().unwrap(),
        b.with_extension("exr").to_str().unwrap(),
        "--out",
        a.to_str().unwrap(),
    ]));
    assert!(e.contains("overwrite"), "{e}");
    assert_eq!(std::fs::read(&a_exr).unwrap(), before);
    // A render whose tag claims 0 spp cannot be weighted: refused, not a NaN image.
    let z = d.path().join("z.exr");
    render_gpu::image_io::write_exr(
        &z,
        &ia,
        &render_gpu::image_io::RenderTag {
            spp: 0,
            scene_hash: tag_of(&a_exr),
            seeds: Vec::new(),
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        },
    )
    .unwrap();
    let e = fails(&stcvae(&[
        "merge",
        z.to_str().unwrap(),
        "--out",
        d.path().join("zm").to_str().unwrap(),
    ]));
    assert!(e.contains("0 spp"), "{e}");
    assert!(!d.path().join("zm.exr").exists());
    // The merge's report, and a copy of an input (another file of the same seed) refused:
    // it would count its samples twice.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(m.with_extension("json")).unwrap()).unwrap();
    assert_eq!(report["spp"], 12);
    assert_eq!(report["seeds"], serde_json::json!([1, 2]));
    assert_eq!(report["seeds_text"], serde_json::json!(["1", "2"]));
    // How the inputs were made, from their reports: one integrator, one device.
    assert_eq!(report["version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(report["integrator"], "stcvae", "{report}");
    assert_eq!(
        report["devices"].as_array().map(Vec::len),
        Some(1),
        "{report}"
    );
    // The merged mean is the spp-weighted mean of the inputs' (4 and 8 spp).
    let mean = |p: &Path| -> Vec<f64> {
        let j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(p.with_extension("json")).unwrap())
                .unwrap();
        (0..3).map(|c| j["mean_rgb"][c].as_f64().unwrap()).collect()
    };
    let (ma, mb, mm) = (mean(&a), mean(&b), mean(&m));
    for c in 0..3 {
        let want = (4.0 * ma[c] + 8.0 * mb[c]) / 12.0;
        assert!(
            (mm[c] - want).abs() <= 1e-6 * want.abs().max(1e-6),
            "{mm:?}"
        );
    }
    let copy = d.path().join("copy.exr");
    std::fs::copy(&a_exr, &copy).unwrap();
    let e = fails(&stcvae(&[
        "merge",
        a_exr.to_str().unwrap(),
        copy.to_str().unwrap(),
        "--out",
        d.path().join("x").to_str().unwrap(),
    ]));
    assert!(e.contains("shares seed 1 with"), "{e}");
    // `--out` naming a directory is refused, not written beside it as DIR.exr.
    let e = fails(&stcvae(&[
        "merge",
        a_exr.to_str().unwrap(),
        b.with_extension("exr").to_str().unwrap(),
        "--out",
        d.path().to_str().unwrap(),
    ]));
    assert!(e.contains("directory"), "{e}");
    // A render that cannot write one of its three files writes none of them: the earlier
    // render's EXR and JSON stay together (an 8-spp EXR beside a 4-spp JSON before). A
    // directory in the PNG's place is refused before rendering (check_out_stem); a write
    // that fails part way through the set is undone by scatter_sim::output's set writer,
    // whose unit tests make each step fail.
    let a_json = a.with_extension("json");
    let (exr_before, json_before) = (
        std::fs::read(&a_exr).unwrap(),
        std::fs::read(&a_json).unwrap(),
    );
    std::fs::remove_file(a.with_extension("png")).unwrap();
    std::fs::create_dir(a.with_extension("png")).unwrap();
    let e = fails(&stcvae(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--spp",
        "2",
        "--seed",
        "9",
        "--out",
        a.to_str().unwrap(),
    ]));
    assert!(e.contains("a.png"), "{e}");
    assert_eq!(std::fs::read(&a_exr).unwrap(), exr_before);
    assert_eq!(std::fs::read(&a_json).unwrap(), json_before);
    assert!(
        std::fs::read_dir(d.path()).unwrap().all(|f| !f
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".partial")),
        "a temporary was left behind"
    );
    // `--out x.exr` writes x.exr, x.png, x.json (not x.exr.exr).
    let x = d.path().join("x.exr");
    ok(&stcvae(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--spp",
        "1",
        "--out",
        x.to_str().unwrap(),
    ]));
    for ext in ["exr", "png", "json"] {
        assert!(x.with_extension(ext).exists(), "missing x.{ext}");
    }
    assert!(!d.path().join("x.exr.exr").exists());
    // A report left from another render (o's: seed 3, 1 spp, beside b's image of seed 2
    // and 8 spp) was taken into the merged report without a word, its integrator as the
    // merge's. Now the merge says so, and records no integrator.
    std::fs::copy(o.with_extension("json"), b.with_extension("json")).unwrap();
    let mut o_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(b.with_extension("json")).unwrap()).unwrap();
    o_json["integrator"] = "pt".into();
    std::fs::write(b.with_extension("json"), o_json.to_string()).unwrap();
    let stale = d.path().join("stale");
    let err = ok(&merge_renders(&a, &b, &stale));
    assert!(
        err.contains("warning: the inputs' reports do not match their images"),
        "{err}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(stale.with_extension("json")).unwrap())
            .unwrap();
    assert_eq!(json["renders_complete"], false, "{json}");
    assert!(json["integrator"].is_null(), "{json}");
}

fn tag_of(p: &Path) -> u64 {
    render_gpu::image_io::read_exr(p)
        .unwrap()
        .1
        .unwrap()
        .scene_hash
}

/// The two devices run one estimator (tested image against image in render-gpu's
/// tests/gpu), so an ST-CVAE render of the CPU and one of the GPU (lavapipe in CI) of the
/// same scene, with different seeds, carry one scene hash and `merge` averages them.
/// Skipped, with the reason, only where no Vulkan adapter exists and not under CI.
#[test]
fn merge_averages_stcvae_renders_of_both_devices() {
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 8);
    let (a, b) = (d.path().join("cpu"), d.path().join("gpu"));
    ok(&render_scene(
        &scene,
        "stcvae",
        "2",
        "1",
        &a,
        &["--device", "cpu"],
    ));
    let args = [
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--integrator",
        "stcvae",
        "--spp",
        "3",
        "--seed",
        "2",
        "--device",
        "gpu",
        "--out",
        b.to_str().unwrap(),
    ];
    if on_vulkan(&args, "merge_averages_stcvae_renders_of_both_devices").is_none() {
        return;
    }
    let m = d.path().join("m");
    ok(&merge_renders(&a, &b, &m));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(m.with_extension("json")).unwrap()).unwrap();
    assert_eq!(json["spp"], 5, "{json}");
    // Both devices named, CPU first as the inputs were given.
    let devices = json["devices"].as_array().unwrap();
    assert_eq!(devices.len(), 2, "{json}");
    assert!(devices[0].as_str().unwrap().starts_with("cpu"), "{json}");
    assert!(devices[1].as_str().unwrap().starts_with("gpu"), "{json}");
    // And each render as its report describes it, in the inputs' order; a merge of the
    // merge lists the same renders (its input is the merged report, not one render).
    let renders = json["renders"].as_array().unwrap();
    assert_eq!(renders.len(), 2, "{json}");
    for (r, (spp, device, seed)) in renders.iter().zip([(2, "cpu", "1"), (3, "gpu", "2")]) {
        assert_eq!(r["spp"], spp, "{json}");
        assert!(r["device"].as_str().unwrap().starts_with(device), "{json}");
        assert_eq!(r["seed_text"], seed, "{json}");
        assert_eq!(r["interrupted"], false, "{json}");
        assert_eq!(r["integrator"], "stcvae", "{json}");
        assert!(r["model_hash"].is_string(), "{json}");
    }
    assert_eq!(json["renders_complete"], true, "{json}");
    let (c, mm) = (d.path().join("c"), d.path().join("mm"));
    ok(&render_scene(
        &scene,
        "stcvae",
        "1",
        "3",
        &c,
        &["--device", "cpu"],
    ));
    ok(&merge_renders(&m, &c, &mm));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(mm.with_extension("json")).unwrap()).unwrap();
    let renders = json["renders"].as_array().unwrap();
    assert_eq!(renders.len(), 3, "{json}");
    assert_eq!(json["renders_complete"], true, "{json}");
    assert_eq!(
        renders[2]["file"],
        c.with_extension("exr").display().to_string(),
        "{json}"
    );
    // A merge written before the list (no `renders`) is one entry marked merged; a render
    // without its report has nulls, and the list no longer accounts for every sample.
    let mjson = m.with_extension("json");
    let mut old: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mjson).unwrap()).unwrap();
    old.as_object_mut().unwrap().remove("renders");
    std::fs::write(&mjson, old.to_string()).unwrap();
    // A missing report is taken quietly; one that is there but damaged is named.
    for damaged in [None, Some("garbage"), Some("[1, 2]")] {
        match damaged {
            None => std::fs::remove_file(c.with_extension("json")).unwrap(),
            Some(text) => std::fs::write(c.with_extension("json"), text).unwrap(),
        }
        let err = ok(&merge_renders(&m, &c, &mm));
        let warned = err.contains(&format!(
            "warning: {}: the render's report could not be read",
            c.with_extension("json").display()
        ));
        assert_eq!(warned, damaged.is_some(), "{damaged:?}: {err}");
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(mm.with_extension("json")).unwrap())
                .unwrap();
        let renders = json["renders"].as_array().unwrap();
        assert_eq!(renders.len(), 2, "{json}");
        assert_eq!(renders[0]["merged"], true, "{json}");
        assert_eq!(renders[0]["spp"], 5, "{json}");
        assert_eq!(renders[0]["devices"].as_array().unwrap().len(), 2, "{json}");
        assert!(renders[1]["spp"].is_null(), "{json}");
        assert_eq!(json["renders_complete"], false, "{json}");
    }
}
