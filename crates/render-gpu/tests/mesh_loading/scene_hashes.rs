//! The scene and view hashes of what is loaded: what they see (faces, a far mesh's place,
//! the model, the environment map's shape) and what they ignore (paths, unread settings);
//! and a mesh far from the origin, moved to it: the camera check, the surface offset and
//! the thin-walls note in the scene file's frame.

use super::*;

/// The scene hash (what `merge` compares) tells apart two meshes of the same vertices cut
/// into different triangles: here a cube whose top face is split along either diagonal.
#[test]
fn the_scene_hash_sees_how_faces_are_cut() {
    let d = tempfile::tempdir().unwrap();
    let split = |top: &str| CUBE_OBJ.replace("f 3 7 8 4\n", top);
    let hash = |obj: String| {
        write(&d, "m.obj", obj.as_bytes());
        let f = render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            "[camera]\norigin = [0.0, 0.0, 6.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 30.0\n\
             width = 8\nheight = 8\n[object]\nmesh = \"m.obj\"\n\
             [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n",
        )
        .unwrap();
        render_gpu::setup::SceneData::build(&f, d.path(), false, &[])
            .unwrap()
            .hash
    };
    let one = hash(split("f 3 7 8\nf 3 8 4\n"));
    assert_eq!(one, hash(split("f 3 7 8\nf 3 8 4\n")), "one mesh, one hash");
    assert_ne!(one, hash(split("f 3 7 4\nf 7 8 4\n")), "the other diagonal");
}

/// The scene hash holds the environment map's shape, not only its pixels: one pixel
/// buffer read as 16×8 or as 32×4 lights the scene differently (both hashed alike).
#[test]
fn the_scene_hash_sees_the_environment_maps_shape() {
    let d = tempfile::tempdir().unwrap();
    write(&d, "m.obj", CUBE_OBJ.as_bytes());
    let pixels: Vec<[f32; 3]> = (0..128).map(|i| [i as f32 / 128.0, 0.5, 1.0]).collect();
    let hash = |w: usize, h: usize| {
        let map = render_gpu::image_io::RgbImage {
            width: w,
            height: h,
            pixels: pixels.clone(),
        };
        let name = format!("env{w}x{h}.exr");
        write(
            &d,
            &name,
            &render_gpu::image_io::encode_untagged_exr(&map).unwrap(),
        );
        let f = render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            "[camera]\norigin = [0.0, 0.0, 6.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 30.0\n\
             width = 8\nheight = 8\n[object]\nmesh = \"m.obj\"\n\
             [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n\
             [environment]\nfile = \"env.exr\"\n",
        )
        .unwrap();
        // One file name in the scene for both maps: the name is not hashed.
        std::fs::copy(d.path().join(&name), d.path().join("env.exr")).unwrap();
        render_gpu::setup::SceneData::build(&f, d.path(), false, &[])
            .unwrap()
            .hash
    };
    let wide = hash(16, 8);
    assert_eq!(wide, hash(16, 8), "one map, one hash");
    assert_ne!(wide, hash(32, 4), "the same pixels in another shape");
}

/// The scene hash keeps what the image depends on and nothing else: one mesh named by
/// another path (a render from another job folder) and settings the integrator never
/// reads (ST-CVAE's with PT, NEE's without NEE) leave it alone, so such renders merge;
/// a setting the integrator does read changes it.
#[test]
fn the_scene_hash_ignores_paths_and_unread_settings() {
    let d = tempfile::tempdir().unwrap();
    write(&d, "m.obj", CUBE_OBJ.as_bytes());
    std::fs::create_dir(d.path().join("job")).unwrap();
    let hash = |mesh: &str, render: &str| {
        let f = render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            &format!(
                "[camera]\norigin = [0.0, 0.0, 6.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 30.0\n\
                 width = 8\nheight = 8\n[object]\nmesh = \"{mesh}\"\n\
                 [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n\
                 [render]\n{render}\n"
            ),
        )
        .unwrap();
        render_gpu::setup::SceneData::build(&f, d.path(), false, &[])
            .unwrap()
            .hash
    };
    let pt = hash("m.obj", "integrator = \"pt\"");
    assert_eq!(
        pt,
        hash("job/../m.obj", "integrator = \"pt\""),
        "another path"
    );
    assert_eq!(
        pt,
        hash(
            "m.obj",
            "integrator = \"pt\"\nnee_samples = 4\nmin_tau = 0.5"
        ),
        "ST-CVAE's settings under PT"
    );
    // Every other ST-CVAE setting is unread under PT too (merge refused such pairs).
    assert_eq!(
        pt,
        hash(
            "m.obj",
            "integrator = \"pt\"\ngrid_resolution = 32\nmax_tau = 50.0\nexact_tau = 8.0\n\
             exact_nee_samples = 2\npath_nee_rays = 2"
        ),
        "ST-CVAE's grid and thresholds under PT"
    );
    assert_ne!(
        pt,
        hash("m.obj", "integrator = \"pt\"\nnee = false"),
        "NEE off"
    );
    let st = |r: &str| hash("m.obj", &format!("integrator = \"stcvae\"\n{r}"));
    assert_ne!(st(""), st("min_tau = 0.5"), "read by ST-CVAE");
    // A threshold written at its default is the default.
    assert_eq!(
        st(""),
        st("min_tau = 1.0\nexact_tau = 20.0"),
        "defaults written out"
    );
    assert_ne!(st(""), st("exact_tau = 8.0"), "read by ST-CVAE");
    // An object's size setting is in its mesh: the default sphere's radius written out is
    // the same scene, another radius is not.
    let shape = |kind: &str, object: &str| {
        let f = render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            &format!(
                "[camera]\norigin = [0.0, 0.0, 6.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 30.0\n\
                 width = 8\nheight = 8\n[object]\nshape = \"{kind}\"\n{object}\n\
                 [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n"
            ),
        )
        .unwrap();
        render_gpu::setup::SceneData::build(&f, d.path(), false, &[])
            .unwrap()
            .hash
    };
    let sphere = |object: &str| shape("sphere", object);
    assert_eq!(
        sphere(""),
        sphere("radius = 0.5"),
        "the default radius written out"
    );
    assert_ne!(sphere(""), sphere("radius = 0.6"), "another radius");
    // So is a boundary's or an environment's default written out (ior = 1.5 given, a black
    // sky given as radiance 0: the same image hashed apart, and `merge` refused the pair).
    let dielectric = "[boundary]\nkind = \"dielectric\"";
    assert_eq!(
        sphere(dielectric),
        sphere(&format!("{dielectric}\nior = 1.5")),
        "the default ior written out"
    );
    assert_ne!(
        sphere(dielectric),
        sphere(&format!("{dielectric}\nior = 1.4")),
        "another ior"
    );
    assert_eq!(
        sphere(""),
        sphere("[environment]\nradiance = [0.0, 0.0, 0.0]"),
        "a black sky written out"
    );
    assert_eq!(
        sphere(""),
        sphere("[environment]\nradiance = [-0.0, 0.0, 0.0]"),
        "a black sky written with -0.0"
    );
    assert_ne!(
        sphere(""),
        sphere("[environment]\nradiance = [0.0, 0.0, 0.1]"),
        "a sky"
    );
    assert_ne!(st(""), st("nee_samples = 4"), "read with NEE");
    assert_eq!(
        st("nee = false"),
        st("nee = false\nnee_samples = 4"),
        "unread without NEE"
    );
    assert_eq!(
        st("nee = false"),
        st("nee = false\nexact_nee_samples = 2\npath_nee_rays = 2"),
        "NEE's other settings unread without NEE"
    );
    // A cube's default size, or the height it already has, written out is the same scene.
    let cube = |object: &str| shape("cube", object);
    assert_eq!(cube(""), cube("size = 1.0"), "the default size written out");
    assert_eq!(
        cube(""),
        cube("height = 1.0"),
        "the cube's own height written out"
    );
    assert_ne!(cube(""), cube("size = 1.5"), "another size");
}

/// The view hash (what `bench error` compares) is one for every integrator and setting
/// of a scene, the model and the build's code included, and another for another camera,
/// medium, light, mesh placement or environment.
#[test]
fn the_view_hash_is_the_scene_without_its_integrator() {
    let d = tempfile::tempdir().unwrap();
    write(&d, "m.obj", CUBE_OBJ.as_bytes());
    let base = "[camera]\norigin = [0.0, 0.0, 6.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 30.0\n\
                width = 8\nheight = 8\n[object]\nmesh = \"m.obj\"\n\
                [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n\
                [[light]]\nkind = \"directional\"\ndirection = [0.0, 1.0, 0.0]\nirradiance = [1.0, 1.0, 1.0]\n";
    let build = |text: &str, model: &[u8]| {
        let f = render_gpu::scene::SceneFile::parse(&d.path().join("s.toml"), text).unwrap();
        let s = render_gpu::setup::SceneData::build(&f, d.path(), false, model).unwrap();
        (s.hash, s.view_hash)
    };
    let (pt, view) = build(&format!("{base}[render]\nintegrator = \"pt\"\n"), &[]);
    for (render, model) in [
        (
            "integrator = \"pt\"\nnee = false\nspp = 7\nseed = 3",
            &b""[..],
        ),
        ("integrator = \"stcvae\"", &b"model"[..]),
        (
            "integrator = \"stcvae\"\nnee = false\nmin_tau = 0.5\nexact_tau = 3.0",
            &b"another model"[..],
        ),
    ] {
        let (h, v) = build(&format!("{base}[render]\n{render}\n"), model);
        assert_ne!(
            h, pt,
            "{render}: the scene hash holds the integrator's settings"
        );
        assert_eq!(v, view, "{render}: one view");
    }
    for (from, to) in [
        ("origin = [0.0, 0.0, 6.0]", "origin = [0.0, 0.5, 6.0]"),
        ("sigma_t = [1.0, 1.0, 1.0]", "sigma_t = [2.0, 1.0, 1.0]"),
        (
            "irradiance = [1.0, 1.0, 1.0]",
            "irradiance = [1.0, 1.0, 0.5]",
        ),
        (
            "width = 8\nheight = 8",
            "width = 8\nheight = 8\n[boundary]\nkind = \"dielectric\"",
        ),
    ] {
        assert!(base.contains(from), "{from}");
        assert_ne!(build(&base.replace(from, to), &[]).1, view, "{to}");
    }
    // An environment map: one view for one map, another for other pixels.
    let sky = |v: f32| {
        let map = render_gpu::image_io::RgbImage {
            width: 8,
            height: 4,
            pixels: vec![[v, 0.5, 1.0]; 32],
        };
        write(
            &d,
            "env.exr",
            &render_gpu::image_io::encode_untagged_exr(&map).unwrap(),
        );
        build(&format!("{base}[environment]\nfile = \"env.exr\"\n"), &[]).1
    };
    let lit = sky(0.25);
    assert_ne!(lit, view, "a map");
    assert_eq!(sky(0.25), lit, "the same map");
    assert_ne!(sky(0.5), lit, "another map");
    // The same cube 40,000 and 40,010 along x before the same camera: recentred, both
    // meshes are the same positions, and only where the mesh was tells the views apart.
    let far = |x: f64| {
        write(&d, "far.obj", cube_obj_at(x).as_bytes());
        let text = base
            .replace("mesh = \"m.obj\"", "mesh = \"far.obj\"")
            .replace("origin = [0.0, 0.0, 6.0]", "origin = [40005.0, 0.0, 40.0]")
            .replace("target = [0.0, 0.0, 0.0]", "target = [40005.0, 0.0, 0.0]");
        build(&text, &[]).1
    };
    assert_ne!(far(40_000.0), far(40_010.0), "the mesh moved");
    // Another mesh: the cube stretched along x.
    write(&d, "m.obj", CUBE_OBJ.replace("v 1", "v 2").as_bytes());
    assert_ne!(build(base, &[]).1, view, "another mesh");
}

/// The camera is checked against the object where the renderer puts them both. A mesh
/// farther from the origin than its own extent is moved to the origin
/// (`setup::recentre`), and the camera moves with it: here CUBE_OBJ (2 across) at
/// x = 51,000, where it rendered not at all before recentring. A camera inside it
/// (0.25, 0.5, 0 from its centre) is refused, named where the scene file put it.
/// Checked at the scene file's position against the moved mesh, it lay 51,000 away and
/// passed. A camera 40 in front still builds.
#[test]
fn a_camera_inside_a_far_mesh_is_refused_after_both_are_moved() {
    let d = tempfile::tempdir().unwrap();
    let obj: String = CUBE_OBJ
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(v) => {
                let c: Vec<f64> = v.split(' ').map(|t| t.parse().unwrap()).collect();
                format!("v {} {} {}\n", c[0] + 51_000.0, c[1], c[2])
            }
            None => format!("{l}\n"),
        })
        .collect();
    write(&d, "far.obj", obj.as_bytes());
    let build = |origin: &str| {
        let text = format!(
            "[camera]\norigin = {origin}\ntarget = [51000.0, 0.0, -10.0]\nfov_deg = 30.0\n\
             width = 8\nheight = 8\n[object]\nmesh = \"far.obj\"\n\
             [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n"
        );
        let f = render_gpu::scene::SceneFile::parse(&d.path().join("s.toml"), &text).unwrap();
        render_gpu::setup::SceneData::build(&f, d.path(), false, &[])
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    let e = build("[51000.25, 0.5, 0.0]").unwrap_err();
    assert!(
        e.contains(
            "camera.origin = [51000.25, 0.5, 0] lies inside the object: the camera must be \
             outside it (in air)"
        ),
        "{e}"
    );
    build("[51000.0, 0.0, 40.0]").unwrap();
}

/// The scene hash holds `extra_hash`, the inputs outside the scene file (the ST-CVAE
/// model's bytes: renders with another model converge to another image and must not
/// merge), and the view hash does not (both show one picture). One scene and integrator
/// here, so only the model can tell the hashes apart.
#[test]
fn the_scene_hash_holds_the_model_and_the_view_hash_does_not() {
    let d = tempfile::tempdir().unwrap();
    write(&d, "m.obj", CUBE_OBJ.as_bytes());
    let f = render_gpu::scene::SceneFile::parse(
        &d.path().join("s.toml"),
        "[camera]\norigin = [0.0, 0.0, 6.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 30.0\n\
         width = 8\nheight = 8\n[object]\nmesh = \"m.obj\"\n\
         [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n\
         [render]\nintegrator = \"stcvae\"\n",
    )
    .unwrap();
    let build = |model: &[u8]| {
        let s = render_gpu::setup::SceneData::build(&f, d.path(), false, model).unwrap();
        (s.hash, s.view_hash)
    };
    let (hash, view) = build(b"model".as_slice());
    assert_eq!(
        build(b"model".as_slice()),
        (hash, view),
        "one model, one hash"
    );
    let (other_hash, other_view) = build(b"another model".as_slice());
    assert_ne!(other_hash, hash, "another model, another scene hash");
    assert_eq!(other_view, view, "another model, one view");
}

/// CUBE_OBJ moved `x` along x.
fn cube_obj_at(x: f64) -> String {
    CUBE_OBJ
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(v) => {
                let c: Vec<f64> = v.split(' ').map(|t| t.parse().unwrap()).collect();
                format!("v {} {} {}\n", c[0] + x, c[1], c[2])
            }
            None => format!("{l}\n"),
        })
        .collect()
}

/// The scene hash, like the view hash, holds where a mesh far from the origin was before
/// `setup::recentre` moved it there: CUBE_OBJ at x = 40,000 and at 40,010 before one
/// camera are the same positions once moved (checked) and the same scene file, so only
/// the shift tells them apart. Hashed alike, `merge` took renders of the two for one
/// scene, and `bench`'s PT reference cache (keyed by the scene hash) served the one's
/// reference for the other.
#[test]
fn the_scene_hash_sees_where_a_far_mesh_was() {
    let d = tempfile::tempdir().unwrap();
    let build = |x: f64| {
        write(&d, "far.obj", cube_obj_at(x).as_bytes());
        let f = render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            "[camera]\norigin = [40005.0, 0.0, 40.0]\ntarget = [40005.0, 0.0, 0.0]\n\
             fov_deg = 30.0\nwidth = 8\nheight = 8\n[object]\nmesh = \"far.obj\"\n\
             [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n",
        )
        .unwrap();
        let s = render_gpu::setup::SceneData::build(&f, d.path(), false, &[]).unwrap();
        (s.hash, s.geo.mesh.positions.clone())
    };
    let (near, moved_near) = build(40_000.0);
    let (far, moved_far) = build(40_010.0);
    assert_eq!(moved_near, moved_far, "moved, the two are one mesh");
    assert_ne!(near, far, "the mesh moved");
}

/// `setup::object_eps`, the surface offset that `experiment` checks its densities against
/// before it renders anything, is the offset the render then uses: the moved mesh's.
/// CUBE_OBJ (2 across) at x = 51,000 has 2 × EPS = 4e-5 once moved; of the file's
/// coordinates it would be 51,001 × EPS ≈ 1.02, and every σ_t above ~1
/// (MAX_SPAWN_DEPTH / eps) was refused as too dense for a cube that renders it.
#[test]
fn the_offset_checked_before_a_render_is_the_renders() {
    let d = tempfile::tempdir().unwrap();
    // CUBE_OBJ at x before a camera on the same line.
    let far = |x: f64| {
        write(&d, "far.obj", cube_obj_at(x).as_bytes());
        render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            &format!(
                "[camera]\norigin = [{x:?}, 0.0, 40.0]\ntarget = [{x:?}, 0.0, 0.0]\n\
                 fov_deg = 30.0\nwidth = 8\nheight = 8\n[object]\nmesh = \"far.obj\"\n\
                 [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n"
            ),
        )
        .unwrap()
    };
    let f = far(51_000.0);
    let eps = render_gpu::setup::object_eps(&f, d.path()).unwrap();
    let rendered = render_gpu::setup::SceneData::build(&f, d.path(), false, &[])
        .unwrap()
        .geo
        .eps;
    assert_eq!(eps, rendered);
    assert_eq!(eps, 2.0 * render_gpu::geometry::EPS);
    // Far on the negative side too: moved by the centre's distance, not by its largest
    // signed coordinate (0 here: left in place, eps would be ≈ 51,001 × EPS).
    let f = far(-51_000.0);
    assert_eq!(
        render_gpu::setup::object_eps(&f, d.path()).unwrap(),
        2.0 * render_gpu::geometry::EPS
    );
}

/// A thin-walls note names its place in the scene file's coordinates: a shell (CUBE_OBJ
/// and CUBE_OBJ shrunk by 1e-5: walls a quarter of the offset, 4e-5) centred at x = 3 is
/// moved to the origin (3 is beyond its extent, 2), and the note's point must lie where
/// the file put the shell, x in [2, 4] (it reads 3.3333; the shift subtracted instead of
/// added would give −2.6667).
#[test]
fn a_thin_walls_note_names_the_place_where_the_file_put_it() {
    let d = tempfile::tempdir().unwrap();
    let mut obj = String::new();
    for (base, s) in [(0u32, 1.0f64), (8, 1.0 - 1e-5)] {
        for l in CUBE_OBJ.lines() {
            if let Some(v) = l.strip_prefix("v ") {
                let c: Vec<f64> = v.split(' ').map(|t| t.parse().unwrap()).collect();
                obj += &format!("v {} {} {}\n", c[0] * s + 3.0, c[1] * s, c[2] * s);
            } else if let Some(f) = l.strip_prefix("f ") {
                let f: Vec<String> = f
                    .split(' ')
                    .map(|i| (i.parse::<u32>().unwrap() + base).to_string())
                    .collect();
                obj += &format!("f {}\n", f.join(" "));
            }
        }
    }
    write(&d, "shell.obj", obj.as_bytes());
    let f = render_gpu::scene::SceneFile::parse(
        &d.path().join("s.toml"),
        "[camera]\norigin = [3.0, 0.0, 6.0]\ntarget = [3.0, 0.0, 0.0]\nfov_deg = 30.0\n\
         width = 8\nheight = 8\n[object]\nmesh = \"shell.obj\"\n\
         [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n",
    )
    .unwrap();
    let notes = render_gpu::setup::SceneData::build(&f, d.path(), false, &[])
        .unwrap()
        .notes;
    let note = notes
        .iter()
        .find(|n| n.contains("of a far side, such as at ["))
        .unwrap_or_else(|| panic!("no thin-walls note with a place: {notes:?}"));
    let x: f64 = note
        .split("such as at [")
        .nth(1)
        .and_then(|r| r.split(',').next())
        .and_then(|x| x.trim().parse().ok())
        .unwrap_or_else(|| panic!("{note}"));
    assert!((2.0..=4.0).contains(&x), "{note}");
}

/// The scene hash and the view hash hold the environment map's pixels and shape, not its
/// name: one map named by another path (from another job folder, or copied elsewhere) is
/// the same scene, as one mesh named by another path is
/// (`the_scene_hash_ignores_paths_and_unread_settings`), so such renders merge and share
/// `bench`'s PT reference.
#[test]
fn the_scene_hashes_ignore_the_environment_maps_path() {
    let d = tempfile::tempdir().unwrap();
    write(&d, "m.obj", CUBE_OBJ.as_bytes());
    std::fs::create_dir(d.path().join("maps")).unwrap();
    let map = render_gpu::image_io::RgbImage {
        width: 8,
        height: 4,
        pixels: (0..32).map(|i| [i as f32 / 32.0, 0.5, 1.0]).collect(),
    };
    let bytes = render_gpu::image_io::encode_untagged_exr(&map).unwrap();
    write(&d, "env.exr", &bytes);
    write(&d, "maps/sky.exr", &bytes);
    let hashes = |file: &str| {
        let f = render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            &format!(
                "[camera]\norigin = [0.0, 0.0, 6.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 30.0\n\
                 width = 8\nheight = 8\n[object]\nmesh = \"m.obj\"\n\
                 [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\n\
                 [environment]\nfile = \"{file}\"\n"
            ),
        )
        .unwrap();
        let s = render_gpu::setup::SceneData::build(&f, d.path(), false, &[]).unwrap();
        (s.hash, s.view_hash)
    };
    assert_eq!(hashes("env.exr"), hashes("maps/sky.exr"));
}
