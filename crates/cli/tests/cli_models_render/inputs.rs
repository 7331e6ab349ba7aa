//! `render`'s command line and scenes: bad arguments and scenes refused in one line, sizes,
//! outputs that must not replace inputs, the JSON, and what it warns or notes about.

use super::*;

/// Arguments that cannot work are refused before any work, in one line naming the
/// argument (clap's usage errors included).
#[test]
fn bad_arguments_name_the_argument() {
    let d = tempfile::tempdir().unwrap();
    let file = d.path().join("file");
    std::fs::write(&file, b"x").unwrap();
    let cases: [(Vec<String>, &str); 23] = [
        // The seed's range (clap's parser said "invalid digit found in string"); a model
        // file that is missing named as --model's value.
        (
            vec!["render".into(), "--seed".into(), "-1".into()],
            "'-1' for '--seed <SEED>': expected a whole number in [0, 2^64)",
        ),
        (
            vec![
                "sample".into(),
                "--model".into(),
                "missing.stcvae".into(),
                "--tau".into(),
                "1".into(),
                "--g".into(),
                "0".into(),
                "--albedo".into(),
                "1".into(),
                "--out".into(),
                d.path().join("s.csv").display().to_string(),
            ],
            "--model missing.stcvae: ",
        ),
        // A file of another command: named for what it is.
        (
            vec![
                "generate".into(),
                "--config".into(),
                "configs/scenes/sphere.toml".into(),
                "--out".into(),
                d.path().join("x.bin").display().to_string(),
            ],
            "sphere.toml: a scene file (for `stcvae render --scene`), not a dataset config",
        ),
        (
            vec![
                "train".into(),
                "--config".into(),
                "configs/dataset/default.toml".into(),
            ],
            "default.toml: a dataset config (for `stcvae generate --config`), not a training config",
        ),
        (vec!["render".into(), "--spp".into(), "0".into()], "--spp"),
        // A budget without end, or an exposure that is 0 as an f32: refused, quoted short.
        (
            vec!["render".into(), "--time-budget".into(), "1e300".into()],
            "'--time-budget <TIME_BUDGET>': 1e300 is out of range: allowed (0, 1e8] seconds",
        ),
        (
            vec!["render".into(), "--time-budget".into(), "abc".into()],
            "'abc' is not a number of seconds",
        ),
        (
            vec!["render".into(), "--exposure".into(), "1e-300".into()],
            "1e-300 is out of range",
        ),
        // Negative values meet the option's range, not "unexpected argument '-1'".
        (
            vec!["render".into(), "--spp".into(), "-1".into()],
            "'-1' for '--spp <SPP>'",
        ),
        (
            vec!["bench".into(), "render".into(), "--k".into(), "-1".into()],
            "allowed [0.001, 1000]",
        ),
        (
            vec![
                "bench".into(),
                "render".into(),
                "--k".into(),
                "1e-300".into(),
            ],
            "1e-300 is out of range: allowed [0.001, 1000]",
        ),
        (
            vec![
                "render".into(),
                "--out".into(),
                format!("{}/", d.path().display()),
            ],
            "names a directory",
        ),
        (
            vec![
                "render".into(),
                "--out".into(),
                file.join("x").display().to_string(),
            ],
            "is not a directory",
        ),
        (
            vec![
                "eval".into(),
                "--samples".into(),
                "1".into(),
                "--out".into(),
                d.path().join("ev").display().to_string(),
            ],
            "--samples",
        ),
        (
            // Held in memory: u64::MAX panicked ("capacity overflow"), 10⁹ aborted.
            vec![
                "eval".into(),
                "--at".into(),
                "5,0,1".into(),
                "--samples".into(),
                "18446744073709551615".into(),
                "--out".into(),
                d.path().join("ev").display().to_string(),
            ],
            "4000000",
        ),
        (
            vec!["bench".into(), "render".into(), "--k".into(), "0".into()],
            "--k",
        ),
        (
            vec!["bench".into(), "sim".into(), "--walks".into(), "0".into()],
            "--walks",
        ),
        // 2^64 walks was taken, and would never have finished.
        (
            vec![
                "bench".into(),
                "sim".into(),
                "--walks".into(),
                "18446744073709551615".into(),
            ],
            "allowed [1024, 16777216]",
        ),
        (
            vec![
                "bench".into(),
                "render".into(),
                "--k".into(),
                "1,2,1".into(),
            ],
            "--k lists 1 twice",
        ),
        // Too dense for the bunny's surface offset: the flag is named, not the file's
        // sigma_t, which the ladder replaced.
        (
            vec![
                "bench".into(),
                "render".into(),
                "--k".into(),
                "1000".into(),
                "--size".into(),
                "8".into(),
            ],
            "--k 1000: the ladder's sigma_t is k × [150.0, 187.5, 125.0]: ",
        ),
        // A render's .json is not the render: named, with the file to give.
        (
            vec![
                "merge".into(),
                "a.exr".into(),
                "b.json".into(),
                "--out".into(),
                d.path().join("m").display().to_string(),
            ],
            "b.json: merge reads a render's .exr (the .json beside it is its report); give b.exr",
        ),
        // Anything else that is not an .exr, beside one: mixed.
        (
            vec![
                "merge".into(),
                "a.exr".into(),
                "b.bin".into(),
                "--out".into(),
                d.path().join("m").display().to_string(),
            ],
            "mixed inputs: b.bin is not a render (.exr)",
        ),
        (
            vec![
                "merge".into(),
                "a.csv".into(),
                "--out".into(),
                d.path().join("m.bin").display().to_string(),
            ],
            "m.bin: CSV inputs can only be merged into a .csv output",
        ),
    ];
    for (args, want) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let e = fails(&stcvae(&args));
        assert!(e.contains(want), "{args:?}: {e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{args:?}: {e}");
    }
    // A missing required argument and an unknown one keep what clap says about them.
    let e = fails(&stcvae(&["merge", "a.bin"]));
    assert!(
        e.contains("required arguments were not provided: --out <OUT>"),
        "{e}"
    );
    assert_eq!(e.trim_end().lines().count(), 1, "{e}");
    let e = fails(&stcvae(&["render", "--sp", "2"]));
    assert!(
        e.contains("unexpected argument '--sp'") && e.contains("'--spp'"),
        "{e}"
    );
    assert_eq!(e.trim_end().lines().count(), 1, "{e}");
}

#[test]
fn bad_scenes_are_one_line_errors() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("s.toml");
    let text = std::fs::read_to_string(root().join("configs/scenes/sphere.toml"))
        .unwrap()
        .replace(
            "albedo = [0.999, 0.99, 0.95]",
            "albedo = [0.999, 1.5, 0.95]",
        );
    std::fs::write(&scene, text).unwrap();
    let out = d.path().join("r");
    let e = fails(&stcvae(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    assert!(
        e.contains("s.toml") && e.contains("medium.albedo[1]") && e.trim().lines().count() == 1,
        "{e}"
    );
    assert!(!out.with_extension("exr").exists());
    // A value of the wrong kind names the kind in words, not serde's Rust type, and a
    // whole-number field its own range, not the type's ([0, 4294967295]).
    let sphere = std::fs::read_to_string(root().join("configs/scenes/sphere.toml")).unwrap();
    for (from, to, want) in [
        (
            "width = 128",
            "width = -16",
            "expected a whole number in [1, 16384]",
        ),
        (
            "width = 128",
            "width = 1.5",
            "expected a whole number in [1, 16384]",
        ),
        (
            "width = 128",
            "'width' = -16",
            "expected a whole number in [1, 16384]",
        ),
        (
            "spp = 64",
            "spp = -1",
            "expected a whole number in [1, 2^32)",
        ),
        (
            "[render]",
            "[render]\npath_nee_rays = 2.5",
            "expected a whole number in [0, 2]",
        ),
        ("fov_deg = ", "fov_deg = \"wide\" # ", "expected a number"),
        // A float is written as given, short (serde wrote 1e308's 309 digits).
        (
            "width = 128",
            "width = 1e308",
            "floating point `1e308`, expected a whole number in [1, 16384]",
        ),
    ] {
        assert!(sphere.contains(from), "{from}");
        std::fs::write(&scene, sphere.replacen(from, to, 1)).unwrap();
        let e = fails(&stcvae(&["render", "--scene", scene.to_str().unwrap()]));
        assert!(
            e.contains("s.toml:") && e.contains(want) && e.trim().lines().count() == 1,
            "{to}: {e}"
        );
    }
    // A mesh path holding a newline and a terminal escape (which cleared the screen) is
    // quoted escaped, on one line.
    let mesh_text = sphere.replacen(
        "shape = \"sphere\"\nradius = 0.5",
        "mesh = \"bad\\nline2\\u001b[2J.glb\"",
        1,
    );
    assert!(
        mesh_text.contains("u001b"),
        "the sphere scene names its shape"
    );
    std::fs::write(&scene, mesh_text).unwrap();
    let e = fails(&stcvae(&["render", "--scene", scene.to_str().unwrap()]));
    assert!(
        e.contains("bad\\nline2\\u{1b}[2J.glb")
            && e.trim().lines().count() == 1
            && !e.contains('\u{1b}'),
        "{e}"
    );
}

/// A box mesh `w` × `w` × `t` centred at x = `x`, wound outward.
fn box_obj(x: f64, w: f64, t: f64) -> String {
    let mut text = String::new();
    for i in 0..8 {
        let (a, b, c) = ((i >> 2) & 1, (i >> 1) & 1, i & 1);
        let pick = |bit: i32, half: f64| if bit == 1 { half } else { -half };
        text += &format!(
            "v {} {} {}\n",
            x + pick(a, w / 2.0),
            pick(b, w / 2.0),
            pick(c, t / 2.0)
        );
    }
    // Vertex 1 + 4a + 2b + c.
    text += "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";
    text
}

/// A mesh far from the origin renders as the same mesh at the origin: the surface offset
/// grew with the coordinates (2e-5 of them), and a unit cube at x = 40,000 (offset 0.8)
/// rendered 5.7 % too transparent, at 51,000 not at all. An absorbing cube (the image is
/// its transmittance) with the camera 4 in front gives the very same image at x = 0 and
/// x = 51,000 (same seed, the same geometry once moved). And an object thinner than the
/// offset resolves is refused (a plate 1000 wide, 0.015 thick, rendered as background),
/// one near that noted; so is an object whose walls are thinner than the offset.
#[test]
fn far_and_thin_objects_render_as_they_should_or_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let scene = |name: &str, x: f64, obj: String| {
        std::fs::write(d.path().join(format!("{name}.obj")), obj).unwrap();
        let text = format!(
            "[camera]\norigin = [{x}, 0.0, 4.0]\ntarget = [{x}, 0.0, 0.0]\nfov_deg = 25.0\n\
             width = 16\nheight = 16\n[object]\nmesh = \"{name}.obj\"\n[medium]\n\
             sigma_t = [0.9, 0.9, 0.9]\nalbedo = [0.0, 0.0, 0.0]\ng = 0.3\n\
             [environment]\nradiance = [1.0, 1.0, 1.0]\n[render]\nintegrator = \"pt\"\n"
        );
        let p = d.path().join(format!("{name}.toml"));
        std::fs::write(&p, text).unwrap();
        p
    };
    let mean = |p: &Path| {
        let out = d.path().join("r");
        ok(&stcvae(&[
            "render",
            p.to_str().unwrap(),
            "--spp",
            "64",
            "--device",
            "cpu",
            "--out",
            out.to_str().unwrap(),
        ]));
        let j: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.path().join("r.json")).unwrap()).unwrap();
        (j["mean_rgb"].clone(), j["scene_hash"].clone())
    };
    let (near, near_hash) = mean(&scene("near", 0.0, box_obj(0.0, 1.0, 1.0)));
    let (far, far_hash) = mean(&scene("far", 51_000.0, box_obj(51_000.0, 1.0, 1.0)));
    assert_eq!(near, far);
    // Where the mesh was is part of the scene: moved alike, the two must not pass for one
    // scene in `merge` (cubes at 40,000 and 40,010 before one camera hashed alike).
    assert_ne!(near_hash, far_hash);
    // Transmittance through the cube, not the background's 1 everywhere.
    assert!(near[0].as_f64().unwrap() < 0.9, "{near}");
    let thin = scene("thin", 0.0, box_obj(0.0, 1000.0, 0.015));
    let e = fails(&stcvae(&[
        "render",
        thin.to_str().unwrap(),
        "--device",
        "cpu",
    ]));
    assert!(
        e.contains("thin.toml: the object is too thin for its size") && e.contains("25000×"),
        "{e}"
    );
    // One sample of a (PT) scene, its notes (stderr).
    let notes = |scene: &Path, name: &str| {
        let out = d.path().join(name);
        ok(&render_scene(
            scene,
            "pt",
            "1",
            "1",
            &out,
            &["--device", "cpu"],
        ))
    };
    let flat = scene("flat", 0.0, box_obj(0.0, 1000.0, 0.2));
    let err = notes(&flat, "flat");
    let walls_note = "of the object's surface lies within the renderer's surface offset";
    assert!(
        err.contains("note: ")
            && err.contains("the object is thin for its size")
            && !err.contains(walls_note),
        "{err}"
    );
    // A unit cube with a cavity whose walls are 5e-6 thick, a quarter of the offset (2e-5
    // of the cube's extent):
    // every face is found, from outside and from the cavity (it rendered as bare
    // background without a word).
    let inner = box_obj(0.0, 1.0 - 1e-5, 1.0 - 1e-5);
    let inner: String = inner
        .lines()
        .map(|l| match l.strip_prefix("f ") {
            Some(f) => {
                let shifted: Vec<String> = f
                    .split(' ')
                    .map(|i| (i.parse::<u32>().unwrap() + 8).to_string())
                    .collect();
                format!("f {}\n", shifted.join(" "))
            }
            None => format!("{l}\n"),
        })
        .collect();
    let shell = scene("shell", 0.0, box_obj(0.0, 1.0, 1.0) + &inner);
    let err = notes(&shell, "shell");
    assert!(
        err.contains(&format!("shell.toml: 100.0 % {walls_note} (2.0000e-5)")),
        "{err}"
    );
}

/// An image larger than the memory the process may allocate is refused before any work,
/// with one line naming the size (Rust aborts on a failed allocation: the 6 GB of a
/// 16,384² image's sums ended in "memory allocation of 6442450944 bytes failed" and a
/// core dump under a 3 GB limit). Before any work: its mesh, which is missing, is never
/// read (the check ran after the mesh, BVH and distance grid were built).
#[cfg(unix)]
#[test]
fn images_beyond_the_memory_limit_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("huge.toml");
    let text = sphere_scene_text(16384)
        .replace("shape = \"sphere\"\nradius = 0.5", "mesh = \"missing.ply\"");
    assert!(
        text.contains("missing.ply"),
        "the sphere scene's object changed"
    );
    std::fs::write(&scene, text).unwrap();
    let out = d.path().join("r");
    // 3 GB of address space: the binary runs, the image's tens of GB cannot be had.
    let shell = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v 3000000 && exec '{}' render --device cpu --spp 1 --scene '{}' --out '{}'",
            env!("CARGO_BIN_EXE_stcvae"),
            scene.display(),
            out.display()
        ))
        .output()
        .unwrap();
    let e = fails(&shell);
    assert!(
        e.contains("huge.toml") && e.contains("16384 x 16384") && e.trim().lines().count() == 1,
        "{e}"
    );
    assert!(!out.with_extension("exr").exists());
}

/// A 1-spp PT render on the CPU of `scene` in `dir` (to `dir`/r), plus `extra`, which must
/// succeed: its standard error output, for the notes and warnings it gives.
fn one_sample_pt(dir: &Path, scene: &str, extra: &[&str]) -> String {
    let mut args = vec![
        "render",
        "--scene",
        scene,
        "--integrator",
        "pt",
        "--spp",
        "1",
        "--device",
        "cpu",
        "--out",
        "r",
    ];
    args.extend_from_slice(extra);
    ok(&common::stcvae(&args, dir))
}

/// A scene without light (no `[[light]]`, a black environment) renders black by design,
/// with a warning saying so; one light is enough to silence it.
#[test]
fn a_scene_without_light_is_warned_about() {
    let d = tempfile::tempdir().unwrap();
    let scene = "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
                 width = 8\nheight = 8\n[object]\nshape = \"sphere\"\n\
                 [medium]\nsigma_t = [10.0, 10.0, 10.0]\nalbedo = [0.9, 0.9, 0.9]\n";
    let lit = format!(
        "{scene}[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\n\
         irradiance = [1.0, 1.0, 1.0]\n"
    );
    for (name, text, warned) in [
        ("dark.toml", scene.to_string(), true),
        ("lit.toml", lit, false),
    ] {
        std::fs::write(d.path().join(name), text).unwrap();
        let err = one_sample_pt(d.path(), name, &[]);
        assert_eq!(
            err.contains("the scene has no light"),
            warned,
            "{name}: {err}"
        );
    }
}

/// A dielectric scene rendered with NEE and a light says how its NEE refracts (exact on
/// flat faces, about 1 % dark on curved ones); with NEE off, index-matched, or without
/// lights it says nothing.
#[test]
fn nee_through_a_dielectric_is_noted_as_approximate_on_curved_faces() {
    let d = tempfile::tempdir().unwrap();
    let base = sphere_scene_text(8);
    let dielectric = base.replace(
        "kind = \"index-matched\"",
        "kind = \"dielectric\"\nior = 1.5",
    );
    assert_ne!(dielectric, base, "the sphere scene's boundary changed");
    let dark = dielectric.split("[[light]]").next().unwrap().to_string()
        + "[environment]\nradiance = [0.1, 0.1, 0.1]\n";
    for (name, text, nee, noted) in [
        ("dielectric.toml", &dielectric, "true", true),
        ("dielectric.toml", &dielectric, "false", false),
        ("matched.toml", &base, "true", false),
        ("dark.toml", &dark, "true", false),
    ] {
        std::fs::write(d.path().join(name), text).unwrap();
        let err = one_sample_pt(d.path(), name, &["--nee", nee]);
        assert_eq!(
            err.contains("NEE through a dielectric boundary refracts at the plane of the face"),
            noted,
            "{name}, nee {nee}: {err}"
        );
    }
}

/// The render's JSON says where the image came from: the version, the exposure, that
/// Ctrl-C did not cut it short (an interrupted render's `interrupted: true` is checked by
/// the interrupt tests), the seed as text too (JSON readers holding doubles round seeds
/// above 2^53); under PT, ST-CVAE's settings are null, not values PT never read.
#[test]
fn the_render_json_describes_the_render() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("r");
    ok(&sphere_pt_render("cpu", &out)
        .args(["--seed", "18446744073709551615", "--exposure", "2"])
        .output()
        .unwrap());
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tmp.path().join("r.json")).unwrap()).unwrap();
    assert_eq!(json["version"], env!("CARGO_PKG_VERSION"), "{json}");
    assert_eq!(json["seed_text"], "18446744073709551615", "{json}");
    assert_eq!(json["exposure"], 2.0, "{json}");
    assert_eq!(json["interrupted"], false, "{json}");
    assert!(json["time_budget"].is_null(), "{json}");
    // The hashes are the EXR tag's.
    let (_, tag) = render_gpu::image_io::read_exr(&tmp.path().join("r.exr")).unwrap();
    let tag = tag.unwrap();
    assert_eq!(
        json["scene_hash"],
        format!("{:016x}", tag.scene_hash),
        "{json}"
    );
    let view = tag.view_hash.expect("a render's tag records its view");
    assert_eq!(json["view_hash"], format!("{view:016x}"), "{json}");
    // The PNG preview is the EXR at --exposure, the factor the JSON records: the same
    // bytes as the EXR's pixels encoded at 2, which differ from those at 1 (the sky's 0.1
    // a channel alone reads 0.2 at 2).
    let (image, _) = render_gpu::image_io::read_exr(&tmp.path().join("r.exr")).unwrap();
    let png = std::fs::read(tmp.path().join("r.png")).unwrap();
    let at = |exposure: f32| render_gpu::image_io::encode_png(&image, exposure).unwrap();
    assert_ne!(at(2.0), at(1.0));
    assert!(png == at(2.0), "the PNG is not the EXR at --exposure 2");
    for key in [
        "model",
        "model_hash",
        "min_tau",
        "max_tau",
        "exact_tau",
        "nee_samples",
        "exact_nee_samples",
        "path_nee_rays",
        "grid_resolution",
    ] {
        assert!(json[key].is_null(), "{key} under PT: {json}");
    }
}

/// The summary line shows the output's name with its control characters escaped, as the
/// errors do: an `--out` holding a newline printed the summary over two lines.
#[cfg(unix)]
#[test]
fn an_output_name_with_a_newline_stays_on_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("a\nb");
    let o = sphere_pt_render("cpu", &out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    let summary = err
        .lines()
        .find(|l| l.contains(" spp in "))
        .unwrap_or_else(|| panic!("no summary line: {err}"));
    assert!(summary.ends_with("a\\nb.{exr,png,json}"), "{summary}");
    assert!(out.with_extension("exr").is_file());
}

/// `--width`/`--height` override the camera's size, one alone keeping its aspect (a 32 x 64
/// camera: width 16 gives 16 x 32, height 8 gives 4 x 8); a derived side beyond the
/// largest image names both flags; the scene may be given without --scene, but not twice,
/// nor as ""; the fields the flags replace are checked as the file writes them.
#[test]
fn render_size_flags_and_a_plain_scene_argument() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("tall.toml");
    let text = sphere_scene_text(128)
        .replace("width = 128", "width = 32")
        .replace("height = 128", "height = 64");
    std::fs::write(&scene, text).unwrap();
    let sc = scene.to_str().unwrap();
    for (flags, want) in [
        (vec!["--width", "16"], (16, 32)),
        (vec!["--height", "8"], (4, 8)),
        (vec!["--width", "6", "--height", "5"], (6, 5)),
        (vec![], (32, 64)),
    ] {
        let out = tmp.path().join("r");
        let mut args = vec![
            "render",
            sc,
            "--integrator",
            "pt",
            "--spp",
            "1",
            "--device",
            "cpu",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(&flags);
        ok(&stcvae(&args));
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(tmp.path().join("r.json")).unwrap()).unwrap();
        assert_eq!(
            (json["width"].as_u64(), json["height"].as_u64()),
            (Some(want.0), Some(want.1)),
            "{flags:?}: {json}"
        );
    }
    let e = fails(&stcvae(&[
        "render", sc, "--width", "16384", "--device", "cpu",
    ]));
    assert!(
        e.contains("--width 16384 with the camera's aspect (32 x 64) gives a height of 32768")
            && e.contains("give --height too"),
        "{e}"
    );
    let e = fails(&stcvae(&["render", sc, "--scene", sc]));
    assert!(e.contains("cannot be used with"), "{e}");
    // A camera side of 0 is named, not hidden by the flag that keeps its aspect.
    let flat = tmp.path().join("flat.toml");
    std::fs::write(
        &flat,
        std::fs::read_to_string(&scene)
            .unwrap()
            .replace("height = 64", "height = 0"),
    )
    .unwrap();
    let e = fails(&stcvae(&["render", flat.to_str().unwrap(), "--width", "8"]));
    assert!(e.contains("camera.height = 0"), "{e}");
    // Nor by flags that replace it: a file that `experiment` and `bench` refuse is
    // refused here too (`--width 8 --height 8` rendered it). On the CPU and into the
    // temporary folder, should one render after all.
    let o = tmp.path().join("o");
    let cpu_to = ["--device", "cpu", "--out", o.to_str().unwrap()];
    let e = fails(&stcvae(
        &[
            &[
                "render",
                flat.to_str().unwrap(),
                "--width",
                "8",
                "--height",
                "8",
            ][..],
            &cpu_to,
        ]
        .concat(),
    ));
    assert!(
        e.contains("camera.height = 0 is out of range: allowed [1, 16384]"),
        "{e}"
    );
    let no_spp = tmp.path().join("no_spp.toml");
    let text = std::fs::read_to_string(&scene).unwrap();
    let spp_line = text
        .lines()
        .find(|l| l.starts_with("spp ="))
        .expect("the scene sets render.spp");
    std::fs::write(&no_spp, text.replace(spp_line, "spp = 0")).unwrap();
    let e = fails(&stcvae(
        &[
            &["render", no_spp.to_str().unwrap(), "--spp", "1"][..],
            &cpu_to,
        ]
        .concat(),
    ));
    assert!(e.contains("render.spp = 0 is out of range"), "{e}");
    // A side out of range is named for its range, not for the memory it would take
    // (which depended on the machine's memory).
    let wide = tmp.path().join("wide.toml");
    std::fs::write(
        &wide,
        text.replace("height = 64", "height = 1")
            .replace("width = 32", "width = 2147483647"),
    )
    .unwrap();
    let e = fails(&stcvae(
        &[&["render", wide.to_str().unwrap()][..], &cpu_to].concat(),
    ));
    assert!(
        e.contains("camera.width = 2147483647 is out of range: allowed [1, 16384]"),
        "{e}"
    );
    let e = fails(&stcvae(&["render", "--width", "0"]));
    assert!(e.contains("--width") && e.contains("16384"), "{e}");
    // An empty scene name, given either way, is refused as such, not as ": cannot read".
    for args in [&["render", ""][..], &["render", "--scene", ""]] {
        let e = fails(&stcvae(args));
        assert!(e.contains("an empty path names no scene file"), "{e}");
    }
}

/// The defaults (scene, model) are relative to the repository root; from another working
/// directory the binary finds them in the checkout it was built from, and writes its
/// outputs where it was started.
#[test]
fn shipped_defaults_are_found_from_another_directory() {
    let d = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| common::stcvae(args, d.path());
    ok(&run(&[
        "render", "--device", "cpu", "--spp", "1", "--out", "r",
    ]));
    let json = std::fs::read_to_string(d.path().join("r.json")).unwrap();
    let model = root().join("models/default.stcvae").canonicalize().unwrap();
    let scene = root()
        .join("configs/scenes/bunny.toml")
        .canonicalize()
        .unwrap();
    // The model's hash is of the file the render read.
    let mut h = render_gpu::hash::Fnv64::new();
    h.write(&std::fs::read(&model).unwrap());
    assert!(
        json.contains(&format!("\"model_hash\": \"{:016x}\"", h.finish())),
        "{json}"
    );
    for (what, p) in [("model", &model), ("scene", &scene)] {
        assert!(
            json.contains(&format!("{:?}", p.display().to_string())),
            "the render's JSON does not name the shipped {what} {}: {json}",
            p.display()
        );
    }
    for ext in ["exr", "png"] {
        assert!(
            d.path().join(format!("r.{ext}")).is_file(),
            "r.{ext} missing"
        );
    }
    let sample = "sample --tau 5 --g 0.4 --albedo 0.9 --samples 10 --out s.csv";
    ok(&run(&common::words(sample)));
    let rows = std::fs::read_to_string(d.path().join("s.csv")).unwrap();
    assert_eq!(rows.lines().count(), 11, "header and 10 walks: {rows}");
    // A scene the user names is taken as given, relative to where the binary runs.
    let err = fails(&run(&["render", "--scene", "configs/scenes/sphere.toml"]));
    assert!(err.contains("configs/scenes/sphere.toml"), "{err}");
}

/// An input that is a named pipe is refused at once by every reader, naming it: opening
/// a FIFO without a writer blocked for ever (a scene, mesh, model, image or dataset given
/// as one hung the command). Each command gets 600 s before the test kills it and fails.
#[cfg(unix)]
#[test]
fn named_pipes_as_inputs_are_refused_not_waited_on() {
    let d = tempfile::tempdir().unwrap();
    let fifo = |name: &str| {
        let p = d.path().join(name);
        let ok = Command::new("mkfifo").arg(&p).status().unwrap().success();
        assert!(ok, "mkfifo {}", p.display());
        p.display().to_string()
    };
    let out = |name: &str| d.path().join(name).display().to_string();
    let scene = d.path().join("s.toml");
    let sphere = std::fs::read_to_string(root().join("configs/scenes/sphere.toml")).unwrap();
    std::fs::write(
        &scene,
        sphere.replace(
            "shape = \"sphere\"\nradius = 0.5",
            &format!("mesh = {:?}", fifo("m.ply")),
        ),
    )
    .unwrap();
    let cases: Vec<Vec<String>> = vec![
        vec![
            "render".into(),
            "--scene".into(),
            fifo("f.toml"),
            "--out".into(),
            out("r"),
        ],
        vec![
            "render".into(),
            "--scene".into(),
            scene.display().to_string(),
            "--device".into(),
            "cpu".into(),
            "--out".into(),
            out("r2"),
        ],
        vec![
            "sample".into(),
            "--model".into(),
            fifo("f.stcvae"),
            "--tau".into(),
            "5".into(),
            "--g".into(),
            "0".into(),
            "--albedo".into(),
            "1".into(),
            "--out".into(),
            out("s.csv"),
        ],
        vec![
            "merge".into(),
            fifo("a.exr"),
            fifo("b.exr"),
            "--out".into(),
            out("m"),
        ],
        vec!["merge".into(), fifo("a.bin"), "--out".into(), out("m.bin")],
        vec!["train".into(), "--config".into(), fifo("t.toml")],
    ];
    for args in cases {
        let mut child = Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .args(&args)
            .current_dir(root())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            // A guard against a hang, not a timing: each case is refused before any work,
            // so even a loaded machine ends it in seconds (`interrupt_when`'s guard too).
            if start.elapsed().as_secs() > 600 {
                child.kill().unwrap();
                panic!("{args:?} waited on a named pipe");
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        };
        let mut err = String::new();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
        assert!(!status.success(), "{args:?}");
        assert!(
            err.contains("is a named pipe (FIFO), not a file") && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
}

/// A delta light beside a disk light is lost to --nee false, and said so: the note came
/// only when every light was delta, and the image came out half as bright without a word.
#[test]
fn a_delta_light_lost_to_nee_off_is_noted() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("two.toml");
    let text = sphere_scene_text(8);
    assert!(text.contains("[environment]\n"));
    let delta = "[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\n\
                 irradiance = [1.0, 1.0, 1.0]\nangular_diameter_deg = 0.0\n\n[environment]\n";
    std::fs::write(&scene, text.replace("[environment]\n", delta)).unwrap();
    let out = d.path().join("o");
    let says = "note: delta lights (1 of the scene's 2) can only be reached by NEE";
    for (nee, noted) in [("false", true), ("true", false)] {
        let err = ok(&render_scene(
            &scene,
            "pt",
            "1",
            "1",
            &out,
            &["--nee", nee, "--device", "cpu"],
        ));
        assert_eq!(err.contains(says), noted, "--nee {nee}: {err}");
    }
}

/// `render --variance` writes OUT.var.exr beside the image in the same set (its statistics
/// are tested in render-gpu's integrators.rs and gpu/agreement.rs): finite, ≥ 0, zero on
/// the constant sky and positive on the object; the JSON names it; `merge` refuses it as a
/// render; too few spp are refused before the render; the GPU writes one too.
#[test]
fn render_variance_writes_a_variance_image() {
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 16);
    let s = scene.to_str().unwrap();
    let out = d.path().join("v");
    let o = out.to_str().unwrap();
    ok(&stcvae(&[
        "render",
        "--scene",
        s,
        "--spp",
        "12",
        "--variance",
        "--device",
        "cpu",
        "--out",
        o,
    ]));
    let var = d.path().join("v.var.exr");
    let (v, tag) = render_gpu::image_io::read_exr(&var).unwrap();
    assert!(tag.is_none(), "the variance image carries no render tag");
    assert!(
        v.pixels
            .iter()
            .flatten()
            .all(|x| x.is_finite() && *x >= 0.0)
    );
    assert_eq!(v.pixels[0], [0.0; 3], "the corner sees the constant sky");
    assert!(
        v.pixels[8 * 16 + 8].iter().all(|x| *x > 0.0),
        "{:?}",
        v.pixels[8 * 16 + 8]
    );
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("v.json")).unwrap()).unwrap();
    // The bare name, beside the JSON (not a path from the render's working directory).
    assert_eq!(json["variance_file"].as_str().unwrap(), "v.var.exr");
    // The root of the variance image's mean over all pixels, per channel (README): from
    // the f32 pixels read back, summed in f64 as the render sums them, so only the JSON's
    // decimal rounding separates the two (1e-9 relative). The mean variance itself (the
    // root left out) is 0.009 here, 10× too small.
    let rms = json["rms_standard_error_rgb"].as_array().unwrap();
    assert_eq!(rms.len(), 3);
    for c in 0..3 {
        let mean = v.pixels.iter().map(|p| f64::from(p[c])).sum::<f64>() / v.pixels.len() as f64;
        let got = rms[c].as_f64().unwrap();
        assert!(
            (got - mean.sqrt()).abs() <= 1e-9 * mean.sqrt(),
            "channel {c}: JSON {got}, √(mean variance) {}",
            mean.sqrt()
        );
    }
    // Nor does an image named v.var replace it: render and merge refuse, before the work
    // (render --out v.var replaced v's variance image without a word).
    let before = std::fs::read(&var).unwrap();
    let as_var = d.path().join("v.var");
    let v_exr = d.path().join("v.exr");
    for args in [
        vec!["render", "--scene", s, "--spp", "2", "--out"],
        vec!["merge", v_exr.to_str().unwrap(), "--out"],
    ] {
        let e = stcvae(&[&args[..], &[as_var.to_str().unwrap()]].concat());
        assert!(
            !e.status.success()
                && common::stderr(&e).contains("is the variance image of the render"),
            "{args:?}: {}",
            common::stderr(&e)
        );
        assert_eq!(std::fs::read(&var).unwrap(), before, "{args:?}");
        assert!(!d.path().join("v.var.png").exists(), "{args:?}");
    }
    let m = d.path().join("m");
    let e = stcvae(&["merge", var.to_str().unwrap(), "--out", m.to_str().unwrap()]);
    assert!(!e.status.success());
    assert!(
        common::stderr(&e).contains("no stcvae render tag")
            && common::stderr(&e).contains("a variance image of `render --variance`?"),
        "{}",
        common::stderr(&e)
    );
    // A render under the same name without --variance removes the old variance image
    // (it would pass for the new image's), and says so.
    let e = stcvae(&["render", "--scene", s, "--spp", "2", "--out", o]);
    assert!(
        e.status.success() && common::stderr(&e).contains("note: removed"),
        "{}",
        common::stderr(&e)
    );
    assert!(!var.exists());
    // Nor is a file the render read: an environment map named sky.var.exr (untagged, no
    // PNG, as a variance image) was deleted by `render --out sky`, which had just read it.
    let sky = d.path().join("sky");
    ok(&stcvae(&[
        "render",
        "--scene",
        s,
        "--spp",
        "6",
        "--variance",
        "--out",
        sky.to_str().unwrap(),
    ]));
    for ext in ["exr", "png", "json"] {
        std::fs::remove_file(d.path().join(format!("sky.{ext}"))).unwrap();
    }
    let lit = d.path().join("lit.toml");
    let text = std::fs::read_to_string(&scene).unwrap();
    assert!(text.contains("[environment]\n"));
    std::fs::write(
        &lit,
        text.replace("[environment]\n", "[environment]\nfile = \"sky.var.exr\"\n"),
    )
    .unwrap();
    let e = stcvae(&[
        "render",
        "--scene",
        lit.to_str().unwrap(),
        "--spp",
        "2",
        "--out",
        sky.to_str().unwrap(),
    ]);
    assert!(
        e.status.success() && !common::stderr(&e).contains("removed"),
        "{}",
        common::stderr(&e)
    );
    assert!(
        d.path().join("sky.var.exr").exists(),
        "the environment map was removed"
    );
    // But a render the user named v.var (its files v.var.exr, .png, .json) is no variance
    // image of v, and stays.
    let named = d.path().join("v.var");
    ok(&stcvae(&[
        "render",
        "--scene",
        s,
        "--spp",
        "2",
        "--out",
        named.to_str().unwrap(),
    ]));
    let e = stcvae(&["render", "--scene", s, "--spp", "2", "--out", o]);
    assert!(
        e.status.success() && !common::stderr(&e).contains("removed"),
        "{}",
        common::stderr(&e)
    );
    assert!(var.exists(), "the render v.var.exr was removed");
    // Nor does --variance write over it (the render v.var's set would hold a variance
    // image as its EXR).
    let before = std::fs::read(&var).unwrap();
    let e = stcvae(&[
        "render",
        "--scene",
        s,
        "--spp",
        "6",
        "--variance",
        "--out",
        o,
    ]);
    assert!(
        !e.status.success()
            && common::stderr(&e).contains("which the variance image would replace"),
        "{}",
        common::stderr(&e)
    );
    assert_eq!(
        std::fs::read(&var).unwrap(),
        before,
        "v.var.exr was overwritten"
    );
    let few = d.path().join("few");
    let e = stcvae(&[
        "render",
        "--scene",
        s,
        "--spp",
        "5",
        "--variance",
        "--out",
        few.to_str().unwrap(),
    ]);
    // Too few spp for a variance, known before the render: refused, nothing rendered (it
    // rendered, wrote no variance image and exited 0).
    assert!(
        !e.status.success()
            && common::stderr(&e).contains("--variance needs at least 6 spp")
            && common::stderr(&e).contains("this render has 5 (--spp)"),
        "{}",
        common::stderr(&e)
    );
    assert!(!d.path().join("few.exr").exists());
    // The GPU keeps squared sums too (its statistics: render-gpu's gpu/agreement.rs): the
    // same set, the sky's variance 0 to rounding, the object's positive. Skipped, with the
    // reason, only where no Vulkan adapter exists and not under CI.
    let g = d.path().join("g");
    let args = [
        "render",
        "--scene",
        s,
        "--spp",
        "12",
        "--variance",
        "--device",
        "gpu",
        "--out",
        g.to_str().unwrap(),
    ];
    if on_vulkan(&args, "render_variance_writes_a_variance_image").is_none() {
        return;
    }
    let (v, _) = render_gpu::image_io::read_exr(&d.path().join("g.var.exr")).unwrap();
    assert!(
        v.pixels[0].iter().all(|x| (0.0..1e-12).contains(x)),
        "{:?}",
        v.pixels[0]
    );
    assert!(
        v.pixels[8 * 16 + 8].iter().all(|x| *x > 0.0),
        "{:?}",
        v.pixels[8 * 16 + 8]
    );
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("g.json")).unwrap()).unwrap();
    assert!(
        json["device"].as_str().unwrap().starts_with("gpu"),
        "{json}"
    );
    assert_eq!(json["rms_standard_error_rgb"].as_array().unwrap().len(), 3);
}

/// Two closed boxes that overlap in one OBJ are rendered as their union (README; tested in
/// render-gpu's integrators.rs and gpu/hard_geometry.rs): `render` notes it, naming the
/// scene and the pieces, and renders. A mesh of more pieces than are checked gets a note
/// that says so.
#[test]
fn overlapping_mesh_pieces_are_noted() {
    let d = tempfile::tempdir().unwrap();
    let boxed = |x0: f32, x1: f32, base: usize| {
        let v: Vec<String> = [(x0, -0.3), (x1, -0.3), (x1, 0.3), (x0, 0.3)]
            .iter()
            .flat_map(|&(x, y)| [-0.3f32, 0.3].map(|z| format!("v {x} {y} {z}\n")))
            .collect();
        // Vertices: (x, y) corners in order, each at z = -0.3 then 0.3: index 2k + zi.
        let quad = |a: usize, b: usize, c: usize, e: usize| {
            format!("f {} {} {} {}\n", a + base, b + base, c + base, e + base)
        };
        let faces = [
            quad(1, 3, 5, 7),
            quad(2, 8, 6, 4),
            quad(1, 2, 4, 3),
            quad(3, 4, 6, 5),
            quad(5, 6, 8, 7),
            quad(7, 8, 2, 1),
        ]
        .concat();
        (v.concat(), faces)
    };
    // `obj` as NAME.obj, the object of the sphere scene NAME.toml, rendered: its stderr.
    let render_mesh = |name: &str, obj: String| {
        std::fs::write(d.path().join(format!("{name}.obj")), obj).unwrap();
        let scene = d.path().join(format!("{name}.toml"));
        std::fs::write(
            &scene,
            sphere_scene_text(8).replace(
                "shape = \"sphere\"\nradius = 0.5",
                &format!("mesh = \"{name}.obj\""),
            ),
        )
        .unwrap();
        let out = stcvae(&[
            "render",
            "--scene",
            scene.to_str().unwrap(),
            "--spp",
            "1",
            "--device",
            "cpu",
            "--out",
            d.path().join("r").to_str().unwrap(),
        ]);
        let err = common::stderr(&out);
        assert!(out.status.success(), "{err}");
        err
    };
    let (v1, f1) = boxed(-0.5, 0.2, 0);
    let (v2, f2) = boxed(-0.2, 0.5, 8);
    let err = render_mesh("two", format!("{v1}{v2}{f1}{f2}"));
    assert!(
        err.contains("note: ") && err.contains("two.toml: pieces 1 and 2 of the mesh overlap"),
        "{err}"
    );
    // Beyond 16 pieces they are not checked, and the render says so: `count` boxes `step`
    // apart.
    let boxes = |count: usize, step: f32| {
        let (mut v, mut f) = (String::new(), String::new());
        for k in 0..count {
            let x0 = -0.5 + k as f32 * step;
            let (vk, fk) = boxed(x0, x0 + 0.04, 8 * k);
            v += &vk;
            f += &fk;
        }
        format!("{v}{f}")
    };
    let err = render_mesh("many", boxes(17, 0.06));
    assert!(
        err.contains(
            "many.toml: the mesh has 17 closed pieces and 204 triangles: beyond 16 \
                      pieces or 2000000 triangles they are not checked for overlaps"
        ) && !err.contains("nesting"),
        "{err}"
    );
    // Beyond 20,000 pairs of overlapping pieces their nesting is not surveyed either (each
    // wound outward): 201 boxes all overlapping.
    let err = render_mesh("many", boxes(201, 1e-4));
    assert!(
        err.contains(
            "the mesh has 201 closed pieces and 2412 triangles: beyond 16 pieces or 2000000 \
             triangles they are not checked for overlaps, and an overlap would render partly \
             as air; join overlapping pieces into one closed surface; beyond 20000 pairs of \
             pieces whose boxes overlap, or 4096 pieces, their nesting is not surveyed either"
        ),
        "{err}"
    );
}

/// A cache entry that exists but cannot be used (here overwritten with other bytes) is
/// rebuilt and written again, and the render says why it took longer: the rebuild used to
/// be silent. The bunny's grid takes ~1.6 s to build on 2 cores, over the 0.1 s from
/// which it is cached; a cache folder of the test's own keeps the user's apart.
#[test]
fn a_damaged_cache_entry_is_rebuilt_with_a_note() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let out = dir.path().join("r");
    let run = || {
        Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .args([
                "render", "--spp", "1", "--width", "16", "--device", "cpu", "--out",
            ])
            .arg(&out)
            .env("STCVAE_CACHE", &cache)
            .current_dir(root())
            .output()
            .unwrap()
    };
    let note = "is damaged or not this mesh's: rebuilding it";
    let first = run();
    assert!(first.status.success(), "{}", common::stderr(&first));
    assert!(!common::stderr(&first).contains(note));
    let entries = || -> Vec<PathBuf> {
        std::fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| {
                p.file_name()
                    .unwrap()
                    .to_string_lossy()
                    .starts_with("grid-")
            })
            .collect()
    };
    let grids = entries();
    if grids.is_empty() {
        // A machine that builds the grid in under 0.1 s does not cache it.
        common::skip(
            "a_damaged_cache_entry_is_rebuilt_with_a_note: the bunny's grid was built too fast to be cached",
        );
        return;
    }
    assert_eq!(grids.len(), 1, "{grids:?}");
    let good = std::fs::read(&grids[0]).unwrap();
    let mut bad = good.clone();
    bad[good.len() / 2] ^= 0xff;
    std::fs::write(&grids[0], &bad).unwrap();
    let second = run();
    let err = common::stderr(&second);
    assert!(second.status.success(), "{err}");
    assert!(err.contains(note) && err.contains("grid-"), "{err}");
    assert_eq!(std::fs::read(&grids[0]).unwrap(), good, "rebuilt as before");
    let third = run();
    assert!(!common::stderr(&third).contains(note));
}
