//! The one-traversal shadow-ray transmittance (Σ t(exits) − Σ t(entries) over unordered
//! crossings) against the crossing-by-crossing walk it replaces: on the non-convex bunny,
//! where shadow rays leave and re-enter (ears, paws), on a sphere's closed forms, on
//! overlapping pieces and on interleaved combs.

mod common;

use glam::Vec3;
use render_gpu::integrator::nee::{transmittance, transmittance_ordered, transmittance_refracted};
use render_gpu::setup::SceneData;
use scatter_sim::WalkRng;

use common::fresnel;

fn bunny(boundary: &str) -> SceneData {
    // The furnace bunny with σ_t = (1, 3, 8) per unit height: transmittances across the
    // bunny range from ~1 to ~1e-3, so lengths are compared where they matter.
    let text = common::furnace_scene(boundary)
        .replace("sigma_t = [5.0, 20.0, 60.0]", "sigma_t = [1.0, 3.0, 8.0]");
    common::build_scene(&text, false)
}

/// Surface crossings of the ray from `x`, walked in order.
fn crossing_count(scene: &SceneData, x: Vec3, dir: Vec3) -> usize {
    let mut o = x;
    let mut n = 0;
    while let Some(h) = scene.geo.intersect(o, dir, f32::INFINITY) {
        n += 1;
        o = scene.geo.spawn(o + dir * h.t, h.normal, dir);
    }
    n
}

fn compare(boundary: &str, seed: u64) {
    let scene = bunny(boundary);
    let mut rng = WalkRng::for_walk(seed, 0);
    let (mut rays, mut off, mut reentering) = (0usize, 0usize, 0usize);
    // transmittance() falls back to the ordered walk when the crossings do not pair up;
    // for those rays the comparison below is the reference against itself. Count the
    // rays the one-traversal sum really served, overall and among the re-entering ones.
    let (mut summed, mut summed_reentering) = (0usize, 0usize);
    for _ in 0..2000 {
        let x = common::random_interior(&scene.geo, &mut rng);
        for _ in 0..4 {
            let dir = common::uniform_direction(&mut rng);
            let served = scene.geo.inside_length(x, dir, |_, _| 1.0).is_some();
            summed += served as usize;
            for channel in 0..3 {
                let a = transmittance(&scene, x, dir, channel);
                let b = transmittance_ordered(&scene, x, dir, channel);
                rays += 1;
                // The ordered walk restarts each segment eps = 2e-5 (relative to the
                // scene) off the surface, which shifts each crossing by ~eps/cos: the two
                // agree to ~1e-4·σ_t per crossing except on grazing crossings.
                // Written so that a NaN counts as a disagreement.
                if !((a - b).abs() <= 2e-3 * b.max(1e-3) + 1e-6) {
                    off += 1;
                }
            }
            // Rays with more than one inside segment: the case the unordered sum is for.
            if crossing_count(&scene, x, dir) > 1 {
                reentering += 1;
                summed_reentering += served as usize;
            }
        }
    }
    // Grazing crossings (cos → 0) may differ by more than the bound; they are rare for
    // uniform directions (P(cos < 0.01) per crossing ≈ 1 %, and only a shift of a few
    // percent of σ·eps/cos shows). Measured: 5 of 24,000 (index-matched), 0 (dielectric);
    // allow 0.1 % of rays.
    assert!(
        off * 1000 <= rays,
        "{boundary}: {off} of {rays} shadow rays disagree with the ordered walk"
    );
    // The test must exercise re-entering rays, or it would not test the sum at all.
    assert!(
        reentering >= 50,
        "{boundary}: only {reentering} rays re-enter the bunny"
    );
    // The one-traversal sum must serve nearly every ray (it refuses only crossings that
    // do not pair up, e.g. a ray exactly through a vertex or edge: measure zero for
    // random rays, so 1 % is generous), the re-entering ones included.
    let directions = rays / 3;
    assert!(
        summed * 100 >= directions * 99,
        "{boundary}: the one-traversal sum served only {summed} of {directions} rays"
    );
    assert!(
        summed_reentering * 100 >= reentering * 99 && summed_reentering >= 50,
        "{boundary}: it served only {summed_reentering} of {reentering} re-entering rays"
    );
}

#[test]
fn one_traversal_matches_ordered_walk_index_matched() {
    compare(r#"kind = "index-matched""#, 5);
}

#[test]
fn one_traversal_matches_ordered_walk_dielectric() {
    compare(
        r#"kind = "dielectric"
ior = 1.5"#,
        6,
    );
}

/// The refracted shadow rays NEE casts through a dielectric (nee.rs, shadow: the depth up
/// to the first way out scaled by its r, the beam's r) from the one traversal against the
/// ordered walk, on shapes where a ray leaves and enters again, so that its first crossing
/// of the boundary is not its only one: the bunny (one mesh: Geometry::crossed's `first`),
/// and the cube with a cavity as one mesh and as overlapping pieces (the union's walk:
/// union_walk's first way out). Every convex scene has one crossing a ray and would not
/// see the sum refract at the wrong one. The bound as in `compare`; at least 50
/// re-entering rays a scene.
#[test]
fn refracted_shadow_rays_refract_at_their_first_way_out() {
    let dielectric = "kind = \"dielectric\"\nior = 1.5";
    let dir = tempfile::tempdir().unwrap();
    let cavity = common::overlapping_parts_scenes(dir.path(), dielectric)
        .into_iter()
        .find(|s| s.0 == "cube with a cavity")
        .unwrap();
    let scenes = [
        ("bunny".to_string(), bunny(dielectric)),
        (
            "cube with a cavity".to_string(),
            common::build_scene(&cavity.1, false),
        ),
        (
            "cube with a cavity, as overlapping pieces".to_string(),
            common::build_scene(&cavity.2, false),
        ),
    ];
    for (seed, (what, scene)) in scenes.iter().enumerate() {
        assert_eq!(
            scene.geo.pieces.is_some(),
            what.contains("pieces"),
            "{what}"
        );
        let mut rng = WalkRng::for_walk(40 + seed as u64, 0);
        let (mut rays, mut off, mut reentering) = (0usize, 0usize, 0usize);
        for _ in 0..2000 {
            let x = common::random_interior(&scene.geo, &mut rng);
            for _ in 0..4 {
                let d = common::uniform_direction(&mut rng);
                reentering += (crossing_count(scene, x, d) > 1) as usize;
                for channel in 0..3 {
                    let a = transmittance_refracted(scene, x, d, channel, false);
                    let b = transmittance_refracted(scene, x, d, channel, true);
                    rays += 1;
                    if !((a - b).abs() <= 2e-3 * b.max(1e-3) + 1e-6) {
                        off += 1;
                    }
                }
            }
        }
        assert!(
            off * 1000 <= rays,
            "{what}: {off} of {rays} refracted shadow rays disagree with the ordered walk"
        );
        assert!(reentering >= 50, "{what}: only {reentering} rays re-enter");
    }
}

#[test]
fn crossings_that_do_not_pair_up_are_refused() {
    let scene = bunny(r#"kind = "index-matched""#);
    // From outside, a ray through the bunny enters as often as it leaves: not an inside
    // origin, so the caller must fall back to the ordered walk.
    let c = Vec3::ZERO.lerp(scene.geo.hi, 0.5) + Vec3::new(0.0, 0.0, 5.0);
    let target = (scene.geo.lo + scene.geo.hi) * 0.5;
    let dir = (target - c).normalize();
    assert!(scene.geo.intersect(c, dir, f32::INFINITY).is_some());
    assert!(scene.geo.inside_length(c, dir, |_, _| 1.0).is_none());
}

/// Closed form on a sphere of radius 0.5: from (0, y, 0) along +x the shadow ray runs
/// √(r² − y²) in the medium and leaves where the air-side cosine is that length over r, so
/// its transmittance is e^(−σ_t·√(r² − y²))·(1 − F(cos)), with Fresnel's unpolarised
/// reflectance written out here (not `optics::fresnel`): F = 0.04 at the normal and 0.0439
/// at y = 0.3 (cos 0.8) for ior 1.5. The icosphere's facets are within 0.03 % of the
/// radius and ~1° of the radial normal, which moves the value by < 0.1 %; the bound is
/// 0.2 %, so a dropped or doubled Fresnel factor (≥ 4 %) or a wrong length fails.
#[test]
fn transmittance_out_of_a_sphere_has_its_closed_form() {
    for (boundary, ior) in [
        ("kind = \"index-matched\"", None),
        ("kind = \"dielectric\"\nior = 1.5", Some(1.5)),
    ] {
        let text = format!(
            "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
             width = 8\nheight = 8\n[object]\nshape = \"sphere\"\nradius = 0.5\n\
             [medium]\nsigma_t = [1.0, 2.0, 4.0]\nalbedo = [0.5, 0.5, 0.5]\n\
             [boundary]\n{boundary}\n"
        );
        let scene = common::build_scene(&text, false);
        for y in [0.0f64, 0.3] {
            let length = (0.25 - y * y).sqrt();
            let t_fresnel = ior.map_or(1.0, |n| 1.0 - fresnel(length / 0.5, n));
            for channel in 0..3 {
                let sigma = [1.0, 2.0, 4.0][channel];
                let want = (-sigma * length).exp() * t_fresnel;
                let x = Vec3::new(0.0, y as f32, 0.0);
                for (how, got) in [
                    ("one traversal", transmittance(&scene, x, Vec3::X, channel)),
                    (
                        "ordered",
                        transmittance_ordered(&scene, x, Vec3::X, channel),
                    ),
                ] {
                    assert!(
                        (f64::from(got) / want - 1.0).abs() < 2e-3,
                        "{boundary}, y = {y}, channel {channel}, {how}: {got}, want {want}"
                    );
                }
            }
        }
    }
}

/// Closed form through overlapping pieces (common::overlapping_parts_scenes): the cube
/// made of two boxes overlapping in x ∈ [−0.2, 0.2], without and with a cubic cavity
/// [−0.15, 0.15]³ inside both, or one across their seam ([−0.35, 0.35] in x). From 500 uniform points of the medium along uniform
/// directions, the shadow ray runs (distance to the cube's face) − (chord through the
/// cavity) in the medium, and crosses the medium's boundary where it leaves the cube
/// and, through the cavity, where it enters and leaves that: each crossing multiplies
/// 1 − F(cos) with a dielectric boundary (F written out as above). The one traversal
/// (sorted crossings, exact distances from the origin) must give it to 0.1 % (f32 lengths
/// are good to ~1e-6). The ordered walk loses a spawn offset eps = 2e-5 of the scene's
/// size (1 here) along the normal at each of its at most 6 crossings, eps/cos along the
/// ray: directions with every |d_i| ≥ 0.2 keep that to 6e-4 of length, so its bound is
/// σ_t·6e-4 + 0.1 % (0.34 % at σ_t = 4, 2.5 % at 40). A face inside the union taken for
/// a boundary counts the overlap (≥ 0.1 in length) or a Fresnel factor (≥ 4 %) twice.
#[test]
fn transmittance_through_overlapping_pieces_has_its_closed_form() {
    let dir = tempfile::tempdir().unwrap();
    for (boundary, ior) in [
        ("kind = \"index-matched\"", None),
        ("kind = \"dielectric\"\nior = 1.5", Some(1.5)),
    ] {
        let scenes = common::overlapping_parts_scenes(dir.path(), boundary);
        for (what, _, text) in scenes.iter().filter(|s| s.0 != "step") {
            let scene = common::build_scene(text, false);
            assert!(scene.geo.pieces.is_some(), "{what}");
            let hollow = what.contains("cavity");
            // The cavity's half extents (common::overlapping_parts_scenes).
            let half = if what.contains("seam") {
                [0.35, 0.15, 0.15]
            } else {
                [0.15; 3]
            };
            let mut rng = WalkRng::for_walk(7, 0);
            let mut rays = 0;
            let mut through_cavity = 0;
            while rays < 500 {
                let x = [(); 3].map(|_| rng.uniform() - 0.5);
                // Points clear of every face by 1e-3 (their spawn offsets are 2e-5).
                let clear = |lo: f64, hi: f64| x.iter().all(|&v| v > lo && v < hi);
                let in_cavity = (0..3).all(|i| x[i].abs() < half[i] + 1e-3);
                if !clear(-0.499, 0.499) || (hollow && in_cavity) {
                    continue;
                }
                let d = common::uniform_direction(&mut rng).as_dvec3();
                if d.abs().min_element() < 0.2 {
                    continue;
                }
                rays += 1;
                // Leaving the cube: the nearest face ahead.
                let (t_exit, cos_exit) = (0..3)
                    .map(|i| ((0.5 * d[i].signum() - x[i]) / d[i], d[i].abs()))
                    .fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a });
                let mut length = t_exit;
                let mut cosines = vec![cos_exit];
                if hollow {
                    // The chord through the cavity, by slabs: entered at the last slab
                    // entry, left at the first slab exit.
                    let slab = |i: usize| {
                        let (a, b) = ((-half[i] - x[i]) / d[i], (half[i] - x[i]) / d[i]);
                        (a.min(b), a.max(b))
                    };
                    let (t_in, cos_in) = (0..3).map(|i| (slab(i).0, d[i].abs())).fold(
                        (f64::NEG_INFINITY, 0.0),
                        |a, b| if b.0 > a.0 { b } else { a },
                    );
                    let (t_out, cos_out) = (0..3)
                        .map(|i| (slab(i).1, d[i].abs()))
                        .fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a });
                    if t_in > 0.0 && t_in < t_out {
                        length -= t_out - t_in;
                        cosines.extend([cos_in, cos_out]);
                        through_cavity += 1;
                    }
                }
                let t_fresnel: f64 = cosines
                    .iter()
                    .map(|&c| ior.map_or(1.0, |n| 1.0 - fresnel(c, n)))
                    .product();
                let xf = glam::DVec3::from_array(x).as_vec3();
                let df = d.as_vec3();
                for channel in 0..3 {
                    let sigma = [4.0, 12.0, 40.0][channel];
                    let want = (-sigma * length).exp() * t_fresnel;
                    for (how, got, bound) in [
                        (
                            "one traversal",
                            transmittance(&scene, xf, df, channel),
                            1e-3,
                        ),
                        (
                            "ordered",
                            transmittance_ordered(&scene, xf, df, channel),
                            sigma * 6e-4 + 1e-3,
                        ),
                    ] {
                        let got = f64::from(got);
                        assert!(
                            (got - want).abs() <= bound * want + 1e-12,
                            "{what}, {boundary}, x = {x:?}, dir = {d:?}, channel {channel}, \
                             {how}: {got}, want {want}"
                        );
                    }
                }
            }
            if hollow {
                // Enough rays through the cavity that its crossings are tested.
                assert!(through_cavity > 20, "{what}: {through_cavity} rays");
            }
        }
    }
}

/// Where pieces overlap, two of them that touch across a gap thinner than the spawn offset
/// (10⁻⁶ here, against 2e-5) make no boundary: paths pass the gap as the inside they were
/// in, and so must shadow rays. A = [−0.5, 0] and B = [10⁻⁶, 0.5] in x (both [−0.5, 0.5]
/// in y and z) touch; C, a bar sticking out of the top across them, makes the mesh one of
/// overlapping pieces. From (−0.3, 0, 0) along d the ray leaves at x = 0.5 after
/// 0.8/d_x less the gap, with one Fresnel factor 1 − F(d_x) (F written out as above); the
/// bound is that of the ordered walk above. Crossed one by one, the exit from A sorted
/// before the entry into B and the walk passed through air: two factors more (−8 % at
/// the normal), and the path loop never sees that boundary.
/// The same mesh's two boxes whose faces share planes (common::overlapping_parts_scenes)
/// also check `Geometry::inside` (the camera check): a point below the shared bottom
/// faces is outside, though a closest-hit walk from it steps past one of the two faces.
#[test]
fn touching_pieces_in_a_union_make_no_boundary() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = common::overlapping_parts_scenes(dir.path(), "kind = \"dielectric\"\nior = 1.5");
    let gap = 1e-6f32;
    let obj = dir.path().join("touching.obj");
    std::fs::write(
        &obj,
        common::boxes_obj(&[
            ([-0.5, -0.5, -0.5], [0.0, 0.5, 0.5]),
            ([gap, -0.5, -0.5], [0.5, 0.5, 0.5]),
            ([-0.2, -0.1, 0.4], [0.2, 0.1, 0.7]),
        ]),
    )
    .unwrap();
    let text = scenes[0].2.replace(
        &dir.path().join("cube2.obj").display().to_string(),
        &obj.display().to_string(),
    );
    let scene = common::build_scene(&text, false);
    assert!(scene.geo.pieces.is_some());
    let x = Vec3::new(-0.3, 0.0, 0.0);
    for d in [Vec3::X, Vec3::new(1.0, 0.2, 0.1).normalize()] {
        let dx = f64::from(d.x);
        let length = 0.8 / dx - f64::from(gap) / dx;
        for channel in 0..3 {
            let sigma = [4.0, 12.0, 40.0][channel];
            let want = (-sigma * length).exp() * (1.0 - fresnel(dx, 1.5));
            for (how, got) in [
                ("one traversal", transmittance(&scene, x, d, channel)),
                ("ordered", transmittance_ordered(&scene, x, d, channel)),
            ] {
                let got = f64::from(got);
                assert!(
                    (got - want).abs() <= (sigma * 6e-4 + 1e-3) * want,
                    "dir {d}, channel {channel}, {how}: {got}, want {want}"
                );
            }
        }
    }
    // Faces apart by less than the spawn offset eps along their normal are one boundary
    // for a ray at any angle: apart by g/|cos| along the ray, which at |cos| = 0.2 and 0.1
    // is beyond eps for g = 1e-5 (eps is 2.4e-5 here), so the merge distance must grow as
    // 1/|cos| too. One way out (the bottom face), not three: the product of the crossings'
    // factors is 0.5, and the length the chord down to it (the gap inside it).
    let apart = 1e-5f32;
    std::fs::write(
        &obj,
        common::boxes_obj(&[
            ([-0.5, -0.5, -0.5], [0.0, 0.5, 0.5]),
            ([apart, -0.5, -0.5], [0.5, 0.5, 0.5]),
            ([-0.2, -0.1, 0.4], [0.2, 0.1, 0.7]),
        ]),
    )
    .unwrap();
    let scene = common::build_scene(&text, false);
    let pieces = scene.geo.pieces.as_ref().expect("the bar overlaps");
    assert!(
        apart < scene.geo.eps && apart / 0.2 > scene.geo.eps,
        "eps {}",
        scene.geo.eps
    );
    let x = Vec3::new(-0.02, 0.0, 0.0);
    for dx in [0.2f32, 0.1] {
        let d = Vec3::new(dx, 0.0, -(1.0 - dx * dx).sqrt());
        let (length, product) = scene
            .geo
            .union_inside_length(pieces, x, d, |_, _| 0.5)
            .unwrap();
        let chord = 0.5 / -d.z;
        assert!(
            product == 0.5 && (length - chord).abs() < 1e-4,
            "|cos| {dx}: length {length} (chord {chord}), product {product}"
        );
    }
    let cube = common::build_scene(&scenes[0].2, false);
    assert!(cube.geo.pieces.is_some());
    for (p, inside) in [
        (Vec3::new(0.0, -0.6, 0.0), false),
        (Vec3::new(0.1, -0.6, 0.1), false),
        (Vec3::new(0.0, 0.0, 0.0), true),
        (Vec3::new(0.4, 0.3, -0.2), true),
        (Vec3::new(0.0, 0.6, 0.0), false),
    ] {
        assert_eq!(cube.geo.inside(p), inside, "{p}");
    }
}

/// Through the combs of [`common::combs_obj`] (their teeth at up to 80 faces along a ray,
/// beyond the 64 crossings the CPU's sorted list holds, `MAX_UNION_CROSSINGS`), from the
/// points of [`common::comb_rays`]: in_union says whether the point is in a tooth, and from
/// inside, the shadow ray's transmittance is [`common::CombRay::transmittance`] whatever the
/// number of crossings (index-matched and dielectric; for the dielectric also the refracted
/// ray NEE casts, whose r = cos θ_i / cos θ_t at the first way out is 1 − 4·10⁻⁷ at these
/// near-normal crossings). 21 % of such points have more than 64 crossings ahead (409 of
/// these 2,000; at least 200 asked). With in_union's fallback OR-ing the pieces instead of
/// flipping them, points between teeth there came out inside; with the ordered walk
/// following at most 64 crossings (`nee::MAX_CROSSINGS`, until 2026-12-07), every such ray
/// came out black. Bound, relative: the ordered walk restarts eps past each face, which may
/// shift the depth by up to σ·eps a crossing, so σ·eps·faces, plus 1e-4 for f32 rounding
/// over ~80 factors (the largest error measured is half its bound).
#[test]
fn rays_through_more_crossings_than_the_list_holds() {
    use render_gpu::integrator::nee::transmittance_refracted;
    let dir = tempfile::tempdir().unwrap();
    for (boundary, ior) in [
        ("kind = \"index-matched\"", None),
        ("kind = \"dielectric\"\nior = 1.5", Some(1.5)),
    ] {
        let (text, teeth) = common::combs_scene(dir.path(), boundary);
        let scene = common::build_scene(&text, false);
        let pieces = scene.geo.pieces.as_ref().expect("the combs' bases overlap");
        let eps = f64::from(scene.geo.eps);
        let rays = common::comb_rays(&teeth, 2000, 17);
        let mut wrong = Vec::new();
        let mut largest = 0f64;
        for r in &rays {
            if scene.geo.in_union(pieces, r.p, r.d) != r.inside {
                wrong.push((r.p, r.d, r.faces));
            }
            if !r.inside {
                continue;
            }
            for channel in 0..3 {
                let sigma = [4.0, 12.0, 40.0][channel];
                let want = r.transmittance(sigma, ior);
                let bound = sigma * eps * r.faces as f64 + 1e-4;
                let mut answers = vec![("one traversal", transmittance(&scene, r.p, r.d, channel))];
                if ior.is_some() {
                    answers.push((
                        "refracted",
                        transmittance_refracted(&scene, r.p, r.d, channel, false),
                    ));
                }
                for (how, got) in answers {
                    let off = (f64::from(got) - want).abs() / want;
                    largest = largest.max(off / bound);
                    // Written so that a NaN fails.
                    assert!(
                        off <= bound,
                        "{boundary}, {how}: from {} along {}, {} faces ahead, channel \
                         {channel}: {got}, want {want}",
                        r.p,
                        r.d,
                        r.faces
                    );
                }
            }
        }
        assert!(
            wrong.is_empty(),
            "{boundary}: in_union wrong at (p, d, faces ahead) {wrong:?}"
        );
        let beyond = rays.iter().filter(|r| r.faces > 64).count();
        eprintln!(
            "{boundary}: {beyond} points beyond 64 faces; largest error {largest:.3} of its bound"
        );
        assert!(
            beyond >= 200,
            "{boundary}: only {beyond} points beyond the list"
        );
        let inside = rays.iter().filter(|r| r.inside).count();
        assert!(inside >= 500, "{boundary}: {inside} points inside");
    }
}
