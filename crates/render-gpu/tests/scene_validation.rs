//! Bad scene files give one clear error naming the field and the allowed range.

use std::path::Path;

use render_gpu::scene::SceneFile;

const BASE: &str = r#"
[camera]
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
fov_deg = 20.0
width = 8
height = 8

[object]
shape = "sphere"

[medium]
sigma_t = [10.0, 10.0, 10.0]
albedo = [0.99, 0.99, 0.99]
g = 0.0
"#;

fn err(text: &str) -> String {
    match SceneFile::parse(Path::new("s.toml"), text) {
        Ok(_) => panic!("accepted a bad scene:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn the_base_scene_is_valid() {
    let s = SceneFile::parse(Path::new("s.toml"), BASE).unwrap();
    assert_eq!(s.camera.up, [0.0, 1.0, 0.0]);
    assert!(s.render.nee);
}

#[test]
fn unknown_keys_are_rejected() {
    let e = err(&BASE.replace("g = 0.0", "g = 0.0\nsigma_s = 1.0"));
    assert!(e.contains("s.toml") && e.contains("sigma_s"), "{e}");
    // Of two misspelt keys, the first in the file is named, with its line (the parsed
    // table was sorted by key, so `zoom` above `aperture` was reported as `aperture`).
    let e = err(&BASE.replace("fov_deg = 20.0", "fov_deg = 20.0\nzoom = 2\naperture = 1"));
    assert!(e.contains("s.toml:6:") && e.contains("`zoom`"), "{e}");
}

#[test]
fn out_of_range_medium_names_the_field() {
    let e = err(&BASE.replace(
        "sigma_t = [10.0, 10.0, 10.0]",
        "sigma_t = [10.0, -1.0, 10.0]",
    ));
    assert!(
        e.contains("medium.sigma_t[1]") && e.contains("[1.1754944e-38, 1e6]"),
        "{e}"
    );
    // Positive in f64 but 0 as the renderers' f32: refused, not a transparent channel.
    let e = err(&BASE.replace(
        "sigma_t = [10.0, 10.0, 10.0]",
        "sigma_t = [10.0, 1e-300, 10.0]",
    ));
    assert!(
        e.contains("medium.sigma_t[1] = 1e-300 is out of range"),
        "{e}"
    );
    let e = err(&BASE.replace("albedo = [0.99, 0.99, 0.99]", "albedo = [0.99, 0.99, 1.2]"));
    assert!(
        e.contains("medium.albedo[2]") && e.contains("[0, 1]"),
        "{e}"
    );
    let e = err(&BASE.replace("g = 0.0", "g = 1.0"));
    assert!(e.contains("medium.g") && e.contains("0.999"), "{e}");
    let e = err(&BASE.replace("g = 0.0", "g = -1.5"));
    assert!(e.contains("medium.g"), "{e}");
    // NaN (TOML's `nan`) fails every comparison: each check must refuse it rather than
    // let it through to the integrators.
    for (from, to, field) in [
        (
            "sigma_t = [10.0, 10.0, 10.0]",
            "sigma_t = [10.0, nan, 10.0]",
            "medium.sigma_t[1]",
        ),
        (
            "albedo = [0.99, 0.99, 0.99]",
            "albedo = [nan, 0.99, 0.99]",
            "medium.albedo[0]",
        ),
        ("g = 0.0", "g = nan", "medium.g"),
    ] {
        let e = err(&BASE.replace(from, to));
        assert!(e.contains(field) && e.contains("out of range"), "{e}");
    }
}

#[test]
fn other_fields_are_checked() {
    let e = err(&BASE.replace("fov_deg = 20.0", "fov_deg = 200.0"));
    assert!(e.contains("camera.fov_deg"), "{e}");
    // Every pixel would get the same ray: refused, the value printed short.
    let e = err(&BASE.replace("fov_deg = 20.0", "fov_deg = 1e-300"));
    assert!(
        e.contains("camera.fov_deg = 1e-300 is out of range: allowed [0.0001, 180)"),
        "{e}"
    );
    // 180° itself: tan 90° and a degenerate camera, outside the half-open range.
    let e = err(&BASE.replace("fov_deg = 20.0", "fov_deg = 180.0"));
    assert!(e.contains("camera.fov_deg = 180 is out of range"), "{e}");
    let e = err(&BASE.replace("width = 8", "width = 0"));
    assert!(e.contains("camera.width"), "{e}");
    let e = err(&BASE.replace("shape = \"sphere\"", "shape = \"sphere\"\nmesh = \"a.glb\""));
    assert!(e.contains("shape") && e.contains("mesh"), "{e}");
    let e = err(&BASE.replace("shape = \"sphere\"", "mesh = \"\""));
    assert!(e.contains("object.mesh = \"\" names no file"), "{e}");
    let e = err(&format!("{BASE}\n[environment]\nfile = \"\"\n"));
    assert!(e.contains("environment.file = \"\" names no file"), "{e}");
    let e = err(&BASE.replace(
        "shape = \"sphere\"",
        "shape = \"sphere\"\nradius = 0.5\nheight = 1.0",
    ));
    assert!(
        e.contains("object.radius and object.height") && e.contains("no effect"),
        "{e}"
    );
    // A cube's size beside a height, and a radius on a shape other than the sphere:
    // either would be ignored without a word.
    let e = err(&BASE.replace(
        "shape = \"sphere\"",
        "shape = \"cube\"\nsize = 2.0\nheight = 1.0",
    ));
    assert!(e.contains("object.size and object.height"), "{e}");
    let e = err(&BASE.replace("shape = \"sphere\"", "shape = \"cube\"\nradius = 0.7"));
    assert!(
        e.contains("object.radius applies to shape = \"sphere\" only"),
        "{e}"
    );
    // Looking straight down with the default up: the message shows the value the file
    // does not.
    let e = err(&BASE.replace("origin = [0.0, 0.0, 4.0]", "origin = [0.0, 4.0, 0.0]"));
    assert!(
        e.contains("camera.up = [0.0, 1.0, 0.0] is parallel") && e.contains("default"),
        "{e}"
    );
    let e = err(&BASE.replace("shape = \"sphere\"", "shape = \"torus\""));
    assert!(e.contains("torus"), "{e}");
    let e = err(&format!(
        "{BASE}\n[boundary]\nkind = \"dielectric\"\nior = 0.5\n"
    ));
    assert!(e.contains("boundary.ior"), "{e}");
    // Above 1 in f64, 1 as an f32: no refraction at all, refused.
    let e = err(&format!(
        "{BASE}\n[boundary]\nkind = \"dielectric\"\nior = 1.0000000000000002\n"
    ));
    assert!(e.contains("boundary.ior") && e.contains("1.0000001"), "{e}");
    let e = err(&format!(
        "{BASE}\n[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, 0.0]\nirradiance = [1.0, 1.0, 1.0]\n"
    ));
    assert!(e.contains("light[0].direction"), "{e}");
    let e = err(&format!("{BASE}\n[render]\nspp = 0\n"));
    assert!(e.contains("render.spp"), "{e}");
    // A max_tau that is 0 in f32, as the renderers hold it: ST-CVAE with no sphere step
    // (PT under its name) rendered without a word.
    let e = err(&format!(
        "{BASE}\n[render]\nintegrator = \"stcvae\"\nmin_tau = 0.0\nmax_tau = 1e-300\n"
    ));
    assert!(e.contains("render.max_tau = 1e-300 is out of range"), "{e}");
    // max_tau equal to min_tau is allowed (max_tau >= min_tau): steps of one size.
    let equal =
        format!("{BASE}\n[render]\nintegrator = \"stcvae\"\nmin_tau = 5.0\nmax_tau = 5.0\n");
    SceneFile::parse(Path::new("s.toml"), &equal).unwrap();
    for bad in ["-1.0", "51.0", "nan"] {
        let e = err(&format!("{BASE}\n[render]\nexact_tau = {bad}\n"));
        assert!(
            e.contains("render.exact_tau") && e.contains("[0, 50]"),
            "{e}"
        );
    }
    assert!(
        SceneFile::parse(
            Path::new("s.toml"),
            &format!("{BASE}\n[render]\nexact_nee_samples = 4\n")
        )
        .is_ok(),
        "exact_nee_samples = 4 is allowed"
    );
    for bad in ["0", "5"] {
        let e = err(&format!("{BASE}\n[render]\nexact_nee_samples = {bad}\n"));
        assert!(
            e.contains("render.exact_nee_samples") && e.contains("[1, 4]"),
            "{e}"
        );
    }
    let e = err("[camera\n");
    assert!(e.starts_with("s.toml:1"), "{e}");
}

/// Values that are finite in the file's f64 but overflow, underflow or coincide in the
/// renderers' f32 are refused by name (they used to panic in the BVH or give NaN images).
#[test]
fn values_that_break_single_precision_are_refused() {
    let cases = [
        (
            "shape = \"sphere\"",
            "shape = \"sphere\"\nradius = 1e39",
            "object.radius",
        ),
        (
            "shape = \"sphere\"",
            "shape = \"sphere\"\nradius = 1e-50",
            "object.radius",
        ),
        (
            "origin = [0.0, 0.0, 4.0]",
            "origin = [1e39, 0.0, 4.0]",
            "camera.origin[0]",
        ),
        // Differs from the origin in f64, equals it in f32.
        (
            "target = [0.0, 0.0, 0.0]",
            "target = [0.0, 0.0, 4.0000000001]",
            "camera.target",
        ),
        // Too short to normalise even in f64.
        (
            "fov_deg = 20.0",
            "fov_deg = 20.0\nup = [0.0, 1e-320, 0.0]",
            "camera.up",
        ),
        (
            "fov_deg = 20.0",
            "fov_deg = 20.0\nup = [0.0, 0.0, 1.0]",
            "camera.up",
        ),
        (
            "sigma_t = [10.0, 10.0, 10.0]",
            "sigma_t = [1e39, 10.0, 10.0]",
            "medium.sigma_t[0]",
        ),
    ];
    for (from, to, field) in cases {
        let e = err(&BASE.replace(from, to));
        assert!(e.contains(field), "{to}: {e}");
    }
    let light = "\n[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = [1.0, 1.0, 1.0]\n";
    let e = err(&format!(
        "{BASE}{}",
        light.replace("irradiance = [1.0", "irradiance = [1e39")
    ));
    assert!(
        e.contains("light[0].irradiance[0]") && e.contains("1e12"),
        "{e}"
    );
    let e = err(&format!(
        "{BASE}{}",
        light.replace("[0.0, 0.0, -1.0]", "[0.0, 0.0, -1e-320]")
    ));
    assert!(e.contains("light[0].direction"), "{e}");
    // Short but normalisable in f64: accepted, and of unit length in the renderer. In f32
    // components below ~1e-21 squared to subnormals: [3e-23, 0, -6e-23] came out 7 % short
    // of unit length and its light as much darker; up = [0, 1e-30, 0] and a direction of
    // [0, 0, -1e-40] were refused though valid.
    let short = format!(
        "{}{}",
        BASE.replace("fov_deg = 20.0", "fov_deg = 20.0\nup = [0.0, 1e-30, 0.0]"),
        light.replace("[0.0, 0.0, -1.0]", "[3e-23, 0.0, -6e-23]")
    );
    let f = SceneFile::parse(Path::new("s.toml"), &short).unwrap();
    let l = render_gpu::light::DirectionalLight::new(&f.lights[0]);
    let want = glam::Vec3::new(1.0, 0.0, -2.0).normalize();
    assert!((l.to_light + want).length() < 1e-6, "{:?}", l.to_light);
    let cam = render_gpu::camera::Camera::new(&f.camera);
    assert!((cam.up() - glam::Vec3::Y).length() < 1e-6, "{:?}", cam.up());
    SceneFile::parse(
        Path::new("s.toml"),
        &format!(
            "{BASE}{}",
            light.replace("[0.0, 0.0, -1.0]", "[0.0, 0.0, -1e-40]")
        ),
    )
    .unwrap();
    let e = err(&format!(
        "{BASE}\n[environment]\nradiance = [1.0, 1e39, 1.0]\n"
    ));
    assert!(e.contains("environment.radiance[1]"), "{e}");
    // A sun disk's radiance E/(π sin²θ) is bounded as an environment's: an irradiance of
    // 1e12 over a 0.001° disk is a radiance of ~4e21, whose squares overflowed --variance.
    // At 0.001° the largest irradiance is π·sin²(8.72665e-6 rad)·1e12 = 239.246.
    let disk = |e: &str, d: &str| {
        format!(
            "{BASE}{}angular_diameter_deg = {d}\n",
            light.replace(
                "irradiance = [1.0, 1.0, 1.0]",
                &format!("irradiance = [1.0, {e}, 1.0]")
            )
        )
    };
    let e = err(&disk("1e12", "0.001"));
    assert!(
        e.contains("light[0].irradiance[1]") && e.contains("angular_diameter_deg = 0.001"),
        "{e}"
    );
    assert!(err(&disk("240.0", "0.001")).contains("allowed up to 2.3925e2"));
    SceneFile::parse(Path::new("s.toml"), &disk("239.0", "0.001")).unwrap();
    // A delta light (diameter 0) has no radiance to bound.
    SceneFile::parse(Path::new("s.toml"), &disk("1e12", "0.0")).unwrap();
}

/// serde's `[f64; 3]` reads three elements of a longer TOML array and drops the rest
/// unseen (an out-of-range fourth albedo rendered); every triple must have exactly three.
#[test]
fn triples_must_have_exactly_three_numbers() {
    let e = err(&BASE.replace(
        "albedo = [0.99, 0.99, 0.99]",
        "albedo = [0.5, 0.5, 0.5, 7.0]",
    ));
    assert!(e.contains("albedo") && e.contains("3 numbers"), "{e}");
    let e = err(&BASE.replace("sigma_t = [10.0, 10.0, 10.0]", "sigma_t = [10.0, 10.0]"));
    assert!(e.contains("sigma_t") && e.contains("3 numbers"), "{e}");
    let e = err(&BASE.replace("origin = [0.0, 0.0, 4.0]", "origin = [0.0, 0.0, 4.0, 1.0]"));
    assert!(e.contains("origin"), "{e}");
    let e = err(&format!(
        "{BASE}\n[environment]\nradiance = [1.0, 1.0, 1.0, 1.0]\n"
    ));
    assert!(e.contains("radiance") && e.contains("3 numbers"), "{e}");
    let e = err(&format!(
        "{BASE}\n[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0, 0.0]\nirradiance = [1.0, 1.0, 1.0]\n"
    ));
    assert!(e.contains("direction"), "{e}");
    // The environment's radiance stays optional.
    let s = SceneFile::parse(
        Path::new("s.toml"),
        &format!("{BASE}\n[environment]\nradiance = [0.5, 0.5, 0.5]\n"),
    )
    .unwrap();
    assert_eq!(s.environment.radiance, Some([0.5; 3]));
    assert!(
        SceneFile::parse(Path::new("s.toml"), &format!("{BASE}\n[environment]\n"))
            .unwrap()
            .environment
            .radiance
            .is_none()
    );
}

/// A camera inside the object rendered a wrong image (paths taken for entering ones, lit
/// as if in air) with exit 0; the scene is refused instead, outside it still renders.
#[test]
fn a_camera_inside_the_object_is_refused() {
    let build = |text: &str| {
        let f = SceneFile::parse(Path::new("s.toml"), text).unwrap();
        render_gpu::setup::SceneData::build(&f, Path::new("."), false, &[])
    };
    for origin in ["[0.0, 0.0, 0.1]", "[0.2, -0.1, 0.0]", "[0.0, 0.0, 0.49]"] {
        let text = BASE.replace("origin = [0.0, 0.0, 4.0]", &format!("origin = {origin}"));
        let e = build(&text)
            .err()
            .expect("a camera inside was accepted")
            .to_string();
        assert!(e.contains("camera.origin") && e.contains("inside"), "{e}");
    }
    for origin in ["[0.0, 0.0, 0.51]", "[0.0, 0.0, 4.0]"] {
        let text = BASE.replace("origin = [0.0, 0.0, 4.0]", &format!("origin = {origin}"));
        assert!(build(&text).is_ok(), "camera at {origin} refused");
    }
}

/// A missing table is named alone: toml reports it at the document's start, and quoting
/// the first line (here a comment) would point at the wrong place.
#[test]
fn a_missing_table_is_named_without_the_first_line() {
    let text = format!("# a sphere\n{}", BASE);
    let medium_at = text.find("[medium]").unwrap();
    let e = err(&text[..medium_at]);
    assert!(
        e.contains(
            "s.toml: the table [medium] is missing (a scene has [camera], [object] and [medium])"
        ),
        "{e}"
    );
    assert!(!e.contains("a sphere"), "{e}");
    // Whichever table is missing, with the file opening with another (it read "missing
    // field `camera` (at the top level or in `[object]`)").
    let without_camera = {
        let (cam, obj) = (
            BASE.find("[camera]").unwrap(),
            BASE.find("[object]").unwrap(),
        );
        format!("{}{}", &BASE[..cam], &BASE[obj..])
    };
    let e = err(&without_camera);
    assert!(e.contains("the table [camera] is missing"), "{e}");
    // A field missing inside a table still points at that table.
    let e = err(&text.replace("sigma_t = [10.0, 10.0, 10.0]\n", ""));
    assert!(e.contains("missing field `sigma_t`"), "{e}");
    // A file opening with the table that lacks the field: toml reports it at byte 0 as a
    // top-level field, so both places are named (it said "missing field `fov_deg`" alone).
    assert!(BASE.trim_start().starts_with("[camera]"), "{BASE}");
    let fov = BASE.lines().find(|l| l.starts_with("fov_deg")).unwrap();
    let e = err(&BASE.trim_start().replace(&format!("{fov}\n"), ""));
    assert!(
        e.ends_with("s.toml: missing field `fov_deg` in [camera]"),
        "{e}"
    );
    // Behind a comment line toml points at the table's header itself.
    let e = err(&format!(
        "# c\n{}",
        BASE.trim_start().replace(&format!("{fov}\n"), "")
    ));
    assert!(
        e.ends_with("s.toml:2: missing field `fov_deg` (in `[camera]`)"),
        "{e}"
    );
}

/// A binary file given as a scene (valid UTF-8 with NULs and escape bytes, as the head of
/// a model file often is) gets one line naming the file and line, with its control
/// characters escaped rather than sent to the terminal.
#[test]
fn binary_input_is_quoted_printably() {
    let e = err("STCVAEMD\u{1}\u{0}\u{0}\u{0} 6\u{5}\u{1b}[2J{");
    assert!(e.starts_with("s.toml:1:"), "{e}");
    assert!(!e.chars().any(char::is_control), "{e:?}");
    assert!(e.contains("\\u{0}") && e.contains("\\u{1b}"), "{e}");
}

/// A float where a whole number belongs is quoted short, as the range messages write
/// numbers: serde wrote `seed = 1e308` out in 309 digits. A table is called a table.
#[test]
fn refused_values_are_described_plainly() {
    let e = err(&format!("{BASE}\n[render]\nseed = 1e308\n"));
    assert!(e.contains("floating point `1e308`"), "{e}");
    assert!(e.len() < 160, "{e}");
    // A short one stays as written.
    let e = err(&format!("{BASE}\n[render]\nseed = 1.5\n"));
    assert!(e.contains("floating point `1.5`"), "{e}");
    // A value where a table belongs is told so, not by the Rust type it would fill.
    let e = err(&format!("environment = 5\n{BASE}"));
    assert!(e.contains("expected a table"), "{e}");
    assert!(!e.contains("struct"), "{e}");
}

/// Another command's file given as a scene is named for what it is (the parser named its
/// first unknown key, `densities` or `[boundary]`), and each shipped file is recognised.
#[test]
fn other_configs_are_named_not_parsed() {
    use render_gpu::scene::{ConfigKind, config_kind};
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    for (dir, kind) in [
        ("scenes", ConfigKind::Scene),
        ("experiments", ConfigKind::Experiment),
        ("train", ConfigKind::Training),
        ("dataset", ConfigKind::Dataset),
    ] {
        for f in std::fs::read_dir(root.join(dir)).unwrap() {
            let p = f.unwrap().path();
            let text = std::fs::read_to_string(&p).unwrap();
            assert_eq!(config_kind(&text), Some(kind), "{}", p.display());
            if kind != ConfigKind::Scene {
                let e = SceneFile::parse(&p, &text).unwrap_err().to_string();
                assert!(e.contains("not a scene file"), "{e}");
            }
        }
    }
}

/// A medium denser than the surface offset allows (σ_t·eps above
/// geometry::MAX_SPAWN_DEPTH = 1; eps is 2e-5 of the object's largest coordinate or
/// extent, 4e-5 for the sphere of radius 1) is refused by channel with the largest σ_t
/// allowed for the object: at σ_t 10⁶ the image came out black without a word. The same density in an object 100 times
/// smaller is fine: the bound is on σ_t times the size.
#[test]
fn a_medium_too_dense_for_the_surface_offset_is_refused() {
    let build = |sigma: &str, radius: &str| {
        let text = BASE.replace("sigma_t = [10.0, 10.0, 10.0]", sigma).replace(
            "shape = \"sphere\"",
            &format!("shape = \"sphere\"\nradius = {radius}"),
        );
        let f = SceneFile::parse(Path::new("s.toml"), &text).unwrap();
        render_gpu::setup::SceneData::build(&f, Path::new("."), false, &[])
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    let e = build("sigma_t = [10.0, 1e5, 10.0]", "1.0").unwrap_err();
    assert!(
        e.contains("medium.sigma_t[1] = 100000 is too dense")
            && e.contains("allowed sigma_t <= 2.5000e4"),
        "{e}"
    );
    build("sigma_t = [10.0, 2.4e4, 10.0]", "1.0").unwrap();
    build("sigma_t = [10.0, 1e5, 10.0]", "0.01").unwrap();
}

/// A mesh that is not there is named with its field and where it was looked for: the
/// message was only "cube.obj: cannot open the mesh", from whatever folder the scene was.
#[test]
fn a_missing_mesh_names_its_field() {
    let dir = tempfile::tempdir().unwrap();
    let text = BASE.replace("shape = \"sphere\"", "mesh = \"nope.obj\"");
    let scene = SceneFile::parse(&dir.path().join("s.toml"), &text).unwrap();
    let Err(e) = render_gpu::setup::object_mesh(&scene, dir.path()) else {
        panic!("a missing mesh loaded");
    };
    let e = e.to_string();
    assert!(
        e.contains("nope.obj: cannot open the mesh of object.mesh = \"nope.obj\" (a relative path is looked for in the scene file's folder)"),
        "{e}"
    );
}

/// A scene without a [render] table renders as one with an empty table, with the README's
/// defaults (PT with NEE, spp 64, seed 1, grid_resolution 128): serde fills a missing
/// table from `RenderDesc::default()`, but the missing fields of a table from their own
/// default functions (`default_spp`, `one`, …), two copies of one list that must agree
/// field by field (compared here as serialised, every field at once).
#[test]
fn a_missing_render_table_takes_the_documented_defaults() {
    let none = SceneFile::parse(Path::new("s.toml"), BASE).unwrap().render;
    let empty = SceneFile::parse(Path::new("s.toml"), &format!("{BASE}\n[render]\n"))
        .unwrap()
        .render;
    assert_eq!(
        serde_json::to_value(&none).unwrap(),
        serde_json::to_value(&empty).unwrap()
    );
    assert_eq!(
        (
            none.integrator,
            none.nee,
            none.spp,
            none.seed,
            none.grid_resolution
        ),
        (render_gpu::scene::IntegratorKind::Pt, true, 64, 1, 128)
    );
}

/// A light's irradiance must be non-negative (README: "each in [0, 1e12]"): a negative
/// one is a light that takes energy away, and rendered negative pixels without a word.
/// Checked for a delta light and for a 10° disk, whose radiance bound E/(π sin²θ) ≤ 1e12
/// does not see the sign either; zero, the range's lower end, stays allowed.
#[test]
fn a_negative_irradiance_is_refused() {
    let light = |irradiance: &str, extra: &str| {
        format!(
            "{BASE}\n[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = {irradiance}\n{extra}"
        )
    };
    for extra in ["", "angular_diameter_deg = 10.0\n"] {
        let e = err(&light("[1.0, -0.5, 1.0]", extra));
        assert!(
            e.contains("light[0].irradiance[1]")
                && e.contains("is out of range: allowed [0, 1e12]"),
            "{extra}: {e}"
        );
    }
    SceneFile::parse(Path::new("s.toml"), &light("[0.0, 0.0, 0.0]", "")).unwrap();
}

/// The environment's radiance must be non-negative (README: allowed [0, 1e12]): a
/// negative sky subtracts light from every path that escapes, negative pixels without a
/// word. Refused alone and as a map's scale (the scene check runs before the map is read,
/// so no file is needed; `Environment::new`'s product check bounds it from above only).
#[test]
fn a_negative_environment_radiance_is_refused() {
    let e = err(&format!(
        "{BASE}\n[environment]\nradiance = [1.0, -0.5, 1.0]\n"
    ));
    assert!(
        e.contains("environment.radiance[1]") && e.contains("is out of range: allowed [0, 1e12]"),
        "{e}"
    );
    let e = err(&format!(
        "{BASE}\n[environment]\nradiance = [-2.0, 1.0, 1.0]\nfile = \"sky.exr\"\n"
    ));
    assert!(e.contains("environment.radiance[0]"), "{e}");
}

/// A sun disk's angular diameter is in [0, 90] (README): a negative one was silently a
/// delta light (`disk_sin2` sees a half-angle below 1e-6 rad), one beyond 90° a disk
/// outside the range the renderers assume (θ_max ≤ 45° in `radiance_toward`). Both ends
/// of the range, and the sun's 0.53°, stay allowed.
#[test]
fn the_disk_diameter_is_checked_at_both_ends() {
    let disk = |d: &str| {
        format!(
            "{BASE}\n[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = [1.0, 1.0, 1.0]\nangular_diameter_deg = {d}\n"
        )
    };
    for bad in ["-10.0", "-1e-9", "90.5", "120.0", "nan"] {
        let e = err(&disk(bad));
        assert!(
            e.contains("light[0].angular_diameter_deg")
                && e.contains("is out of range: allowed [0, 90]"),
            "{bad}: {e}"
        );
    }
    for good in ["0.0", "0.53", "90.0"] {
        SceneFile::parse(Path::new("s.toml"), &disk(good))
            .unwrap_or_else(|e| panic!("angular_diameter_deg = {good} refused: {e}"));
    }
}

/// `object.height` is range-checked like radius and size ([1e-6, 1e6]), for a shape and
/// for a mesh: a negative height scaled the object by a negative factor (mirrored through
/// its centre, its triangles' winding reversed), 0 collapsed it, 2e6 is beyond the
/// scene-value bound of the other lengths, and NaN is refused as every other field's is.
#[test]
fn object_height_is_range_checked() {
    for bad in ["-1.0", "0.0", "1e-9", "2e6", "nan"] {
        for object in ["shape = \"sphere\"", "mesh = \"a.obj\""] {
            let text = BASE.replace("shape = \"sphere\"", &format!("{object}\nheight = {bad}"));
            let e = err(&text);
            assert!(
                e.contains("object.height = ")
                    && e.contains("is out of range: allowed [1e-6, 1e6]"),
                "{object}, height {bad}: {e}"
            );
        }
    }
    SceneFile::parse(
        Path::new("s.toml"),
        &BASE.replace("shape = \"sphere\"", "shape = \"sphere\"\nheight = 2.0"),
    )
    .unwrap();
}

/// `object.size` is the cube's edge and nothing else's (README: "cube only: size"): on a
/// sphere, the torus knot or a mesh it would be read and ignored (`setup::object_mesh`
/// uses it for the cube alone), the object rendered at its default size without a word.
/// The cube keeps it.
#[test]
fn a_size_on_a_shape_other_than_the_cube_is_refused() {
    for object in [
        "shape = \"sphere\"",
        "shape = \"torus-knot\"",
        "mesh = \"a.obj\"",
    ] {
        let text = BASE.replace("shape = \"sphere\"", &format!("{object}\nsize = 2.0"));
        let e = err(&text);
        assert!(
            e.contains("object.size applies to shape = \"cube\" only"),
            "{object}: {e}"
        );
    }
    SceneFile::parse(
        Path::new("s.toml"),
        &BASE.replace("shape = \"sphere\"", "shape = \"cube\"\nsize = 2.0"),
    )
    .unwrap();
}

/// render.grid_resolution is checked against its documented range [4, MAX_GRID = 512]
/// (512³ cells of 8 bytes is already 1 GiB before the candidate lists). The deserializer
/// (`whole`) takes any whole number a u32 holds and leaves the range to `validate`, so
/// without that check 513 or 100000 (10¹⁵ cells) went on to the grid's allocation and 3
/// gave a grid coarser than the least allowed. The bounds themselves are accepted.
#[test]
fn the_grid_resolution_is_checked_against_its_range() {
    for bad in ["3", "513", "100000"] {
        let e = err(&format!("{BASE}\n[render]\ngrid_resolution = {bad}\n"));
        assert!(
            e.contains(&format!(
                "render.grid_resolution = {bad} is out of range: allowed [4, 512]"
            )),
            "{e}"
        );
    }
    for good in ["4", "512"] {
        let text = format!("{BASE}\n[render]\ngrid_resolution = {good}\n");
        let s = SceneFile::parse(Path::new("s.toml"), &text).unwrap();
        assert_eq!(s.render.grid_resolution.to_string(), good);
    }
}

/// An index of refraction given to an index-matched boundary (the default kind, or named)
/// is refused: index-matched means ior = 1, so `[boundary] ior = 1.5` without
/// `kind = "dielectric"` would render with no refraction and no Fresnel reflection while
/// the file asks for glass. Index-matched without an ior and a dielectric with one stay
/// valid.
#[test]
fn an_index_matched_boundary_refuses_an_ior() {
    for boundary in ["ior = 1.5", "kind = \"index-matched\"\nior = 1.33"] {
        let e = err(&format!("{BASE}\n[boundary]\n{boundary}\n"));
        assert!(
            e.contains("boundary.ior applies to kind = \"dielectric\" only"),
            "{boundary}: {e}"
        );
    }
    for boundary in [
        "kind = \"index-matched\"",
        "kind = \"dielectric\"\nior = 1.33",
    ] {
        SceneFile::parse(
            Path::new("s.toml"),
            &format!("{BASE}\n[boundary]\n{boundary}\n"),
        )
        .unwrap();
    }
}

/// Coordinates are bounded in magnitude, below −MAX_SCENE_VALUE (−1e6) as above +1e6:
/// the existing cases are all positive. −2e6 is finite in f32 but past the bound the
/// renderers' f32 offsets rely on; −1e39 overflows f32 to −inf, which must be named by
/// its field rather than reported as "target equals origin". A light's direction of
/// −1e39 normalises in f64 but is out of range all the same. The bound itself is accepted.
#[test]
fn coordinates_below_minus_the_bound_are_refused() {
    for (from, to, field) in [
        (
            "origin = [0.0, 0.0, 4.0]",
            "origin = [-2e6, 0.0, 4.0]",
            "camera.origin[0]",
        ),
        (
            "target = [0.0, 0.0, 0.0]",
            "target = [-2e6, 0.0, 0.0]",
            "camera.target[0]",
        ),
        (
            "origin = [0.0, 0.0, 4.0]",
            "origin = [0.0, 0.0, -1e39]",
            "camera.origin[2]",
        ),
    ] {
        let e = err(&BASE.replace(from, to));
        assert!(
            e.contains(field) && e.contains("allowed [-1e6, 1e6]"),
            "{to}: {e}"
        );
    }
    let e = err(&format!(
        "{BASE}\n[[light]]\nkind = \"directional\"\ndirection = [-1e39, 0.0, -1.0]\n\
         irradiance = [1.0, 1.0, 1.0]\n"
    ));
    assert!(
        e.contains("light[0].direction[0]") && e.contains("allowed [-1e6, 1e6]"),
        "{e}"
    );
    SceneFile::parse(
        Path::new("s.toml"),
        &BASE.replace("origin = [0.0, 0.0, 4.0]", "origin = [-1e6, 0.0, 4.0]"),
    )
    .unwrap();
}
