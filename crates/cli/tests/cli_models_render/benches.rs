//! `bench decoders`, `bench render`, `bench devices` and `bench error` through the binary:
//! what they print, their checks before rendering, and the stored PT pairs.

use super::*;

/// `bench decoders` on a Vulkan adapter: a row per decoder and the branch verdict. The
/// bench itself fails when the GPU's decoder sums differ from the CPU decoder's (checked on
/// its first items), so a passing run also shows the timed probe computes the decoders.
/// Which verdict it prints is the driver's (Mesa 22 runs every branch, Mesa 25 and hardware
/// GPUs skip), so only its presence is asserted.
#[test]
fn bench_decoders_prints_each_decoder_and_the_branch_verdict() {
    let args = ["bench", "decoders", "--draws", "1024", "--rounds", "3"];
    let Some(out) = on_vulkan_any(
        &args,
        &[],
        "bench_decoders_prints_each_decoder_and_the_branch_verdict",
    ) else {
        return;
    };
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    for name in ["LengthGen", "PathGen", "EventGen"] {
        let row = text
            .lines()
            .find(|l| l.trim_start().starts_with(name))
            .unwrap_or_else(|| panic!("no {name} row: {text}"));
        assert!(row.trim_end().ends_with('x'), "{row}");
        // GPU/CPU is the GPU's rate over the CPU's on all threads, as printed (within the
        // rounding of the three printed figures).
        let fields: Vec<&str> = row.split_whitespace().skip(3).collect();
        let (ratio, rates) = fields.split_last().unwrap();
        let ratio: f64 = ratio.trim_end_matches('x').parse().unwrap();
        let r = printed_rates(rates, &text);
        assert_eq!(r.len(), 3, "{row}");
        let ((cn, dcn), (g, dg)) = (r[1], r[2]);
        let want = g / cn;
        assert!(
            (ratio - want).abs() <= 0.005 + want * (dg / g + dcn / cn) + 1e-9,
            "{row}"
        );
    }
    // Any of the three verdicts (runs this short may land between the outcomes); which
    // one a ratio gives is bench_decoders.rs's unit test.
    assert!(
        text.contains("skips branches no lane takes")
            || text.contains("runs every branch of an `if`")
            || text.contains("inconclusive, between the two outcomes"),
        "{text}"
    );
    // Out of range: a one-line error naming the flag.
    let err = fails(&stcvae(&["bench", "decoders", "--rounds", "0"]));
    assert!(err.contains("--rounds"), "{err}");
}

/// On a GPU the stored PT pair is keyed by the kernels' settings from the environment
/// too: a pair timed with one workgroup size supplied the speed-up of a run with another.
#[test]
fn a_gpu_pt_pair_is_stored_per_kernel_setting() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("pt");
    let args = [
        "bench",
        "render",
        "--device",
        "gpu",
        "--k",
        "0.25",
        "--spp",
        "6",
        "--size",
        "8",
        "--pt-cache",
        cache.to_str().unwrap(),
    ];
    // With the default workgroup (64) named, so that an inherited setting changes nothing.
    let run = |workgroup: &str| -> Option<String> {
        let out = on_vulkan_any(
            &args,
            &[("STCVAE_GPU_WORKGROUP", workgroup)],
            "a_gpu_pt_pair_is_stored_per_kernel_setting",
        )?;
        ok(&out);
        Some(String::from_utf8_lossy(&out.stdout).into_owned())
    };
    let hit = "PT from --pt-cache";
    let Some(first) = run("64") else {
        return;
    };
    assert!(!first.contains(hit), "{first}");
    assert!(run("64").unwrap().contains(hit));
    assert!(!run("32").unwrap().contains(hit));
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 2);
}

/// `bench render --pt-cache`: a second run reuses PT's pair, also when only ST-CVAE's own
/// settings change; another spp, NEE off or another set of seeds is a miss; a bad ST-CVAE
/// setting fails before any render; a damaged pair is rendered again and replaced.
#[test]
fn bench_render_reuses_stored_pt_pairs() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("pt");
    let cache_s = cache.to_str().unwrap();
    let bench = |spp: &str, extra: &[&str]| {
        let mut args = vec![
            "bench",
            "render",
            "--k",
            "0.25",
            "--spp",
            spp,
            "--size",
            "8",
            "--pt-cache",
            cache_s,
        ];
        args.extend_from_slice(extra);
        stcvae(&args)
    };
    let stdout = |out: Output| {
        ok(&out);
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let hit = "PT from --pt-cache";
    assert!(!stdout(bench("6", &[])).contains(hit));
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 1);
    assert!(stdout(bench("6", &[])).contains(hit));
    let st_only = [
        "--max-tau",
        "50",
        "--nee-samples",
        "1",
        "--min-tau",
        "1",
        "--exact-nee-samples",
        "2",
    ];
    assert!(stdout(bench("6", &st_only)).contains(hit));
    assert!(!stdout(bench("12", &[])).contains(hit));
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 2);
    // Refused before PT renders: no third file appears.
    let err = fails(&bench("18", &["--nee-samples", "0"]));
    assert!(err.contains("nee_samples"), "{err}");
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 2);
    // NEE off is another PT scene (the flag enters the scene hash): a miss, and said so.
    let off = stdout(bench("6", &["--nee", "false"]));
    assert!(off.contains("NEE off") && !off.contains(hit), "{off}");
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 3);
    assert!(stdout(bench("6", &[])).contains("NEE on"));
    // Another set of seeds is another realisation: a miss the first time, stored apart.
    let set1 = stdout(bench("6", &["--seeds", "1"]));
    assert!(
        set1.contains("seeds PT [15, 16], ST-CVAE [17, 18]"),
        "{set1}"
    );
    assert!(!set1.contains(hit), "{set1}");
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 4);
    assert!(stdout(bench("6", &["--seeds", "1"])).contains(hit));
    assert!(stdout(bench("6", &[])).contains("seeds PT [11, 12], ST-CVAE [13, 14]"));
    // A stored pair edited (its first pixel's red mean given a leading "-1") is not used:
    // PT is rendered again with a note naming the file, and the file replaced, so that the
    // next run reads it (it stopped the bench, asking for the file to be deleted).
    let before = stdout(bench("6", &[]));
    assert!(before.contains(hit), "{before}");
    for f in std::fs::read_dir(&cache).unwrap() {
        let f = f.unwrap().path();
        let text = std::fs::read_to_string(&f).unwrap();
        assert!(text.contains("\"mean\":[["), "{}", f.display());
        std::fs::write(&f, text.replace("\"mean\":[[", "\"mean\":[[-1")).unwrap();
    }
    let out = bench("6", &[]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    let again = stdout(out);
    assert!(
        err.contains("pt-v") && err.contains("damaged") && err.contains("rendered again"),
        "{err}"
    );
    assert!(!again.contains(hit), "{again}");
    assert!(stdout(bench("6", &[])).contains(hit));
}

/// `bench render --save`: both images, the z map and the pixel table, whose means are the
/// images' pixels (the same f32 values, printed exactly) and whose variances (of the
/// two-seed means; their values are not recomputed here) are non-negative, and zero on
/// the constant background in both integrators.
#[test]
fn bench_render_save_writes_images_and_the_pixel_table() {
    let dir = tempfile::tempdir().unwrap();
    let save = dir.path().join("b");
    // A bench refused after --save was checked (here for its --pt-cache, under a file)
    // leaves no folder: --save made it at once, and an empty one stayed behind.
    let afile = dir.path().join("afile");
    std::fs::write(&afile, b"").unwrap();
    let bench = |more: &[&str]| {
        let args = [
            "bench",
            "render",
            "--k",
            "0.25",
            "--spp",
            "6",
            "--size",
            "8",
            "--save",
            save.to_str().unwrap(),
        ];
        stcvae(&[&args[..], more].concat())
    };
    let cache = afile.join("cache");
    let err = fails(&bench(&["--pt-cache", cache.to_str().unwrap()]));
    assert!(err.contains("--pt-cache"), "{err}");
    assert!(
        !save.exists(),
        "--save's folder was made before the bench ran"
    );
    ok(&bench(&[]));
    for f in [
        "k0.25_pt.exr",
        "k0.25_pt.png",
        "k0.25_stcvae.exr",
        "k0.25_stcvae.png",
        "k0.25_z.png",
    ] {
        assert!(save.join(f).is_file(), "{f} missing");
    }
    let (pt, pt_tag) = render_gpu::image_io::read_exr(&save.join("k0.25_pt.exr")).unwrap();
    let (st, st_tag) = render_gpu::image_io::read_exr(&save.join("k0.25_stcvae.exr")).unwrap();
    // Each image is the mean of its pair's two seeds (set 0: PT 11 and 12, ST-CVAE 13 and
    // 14), and its tag says so, so that merge knows them (it compared pixels only).
    assert_eq!(pt_tag.unwrap().seeds, vec![11, 12]);
    assert_eq!(st_tag.unwrap().seeds, vec![13, 14]);
    let csv = std::fs::read_to_string(save.join("k0.25_pixels.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("x,y,channel,pt_mean,pt_var,stcvae_mean,stcvae_var")
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 8 * 8 * 3);
    let (mut object, mut background) = (0, 0);
    for r in &rows {
        let (i, c) = (r[1] as usize * 8 + r[0] as usize, r[2] as usize);
        assert_eq!(r[3] as f32, pt.pixels[i][c], "pixel {i} channel {c}");
        assert_eq!(r[5] as f32, st.pixels[i][c], "pixel {i} channel {c}");
        assert!(r[4] >= 0.0 && r[6] >= 0.0, "{r:?}");
        if r[4] == 0.0 && r[6] == 0.0 {
            background += 1;
        } else {
            object += 1;
        }
    }
    // The bunny covers part of the 8×8 image: both kinds of pixel occur.
    assert!(object > 0 && background > 0, "{object} / {background}");
}

/// `bench devices`: PT and ST-CVAE rendered on the GPU (lavapipe in CI) and on the CPU,
/// a row per density and integrator with the GPU/CPU ratio of paths/s. Skipped, with the
/// reason, only where no Vulkan adapter exists and not under CI.
/// `bench devices` builds every density's scene before it renders any: a density too deep
/// for the bunny's surface offset (k = 300, above the README's k ≈ 265) failed only after
/// the k = 1 rows had rendered (minutes on lavapipe). Now it fails before the first row,
/// and before the banner and the table's head.
#[test]
fn bench_devices_checks_every_density_before_rendering() {
    let Some(out) = on_vulkan_any(
        &common::words(
            "bench devices --scene configs/scenes/bunny.toml --size 8 --spp 1 --k 1,300",
        ),
        &[],
        "bench_devices_checks_every_density_before_rendering",
    ) else {
        return;
    };
    let e = fails(&out);
    assert!(e.contains("too dense") && e.contains("σ_t × 300"), "{e}");
    // Not even the banner or the table's head, as if a row were to follow.
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.trim().is_empty(), "printed before the refusal: {text}");
}

/// `bench render` holds both integrators' pairs beside a render's buffers: it checked no
/// memory at all, and `--size 4096` under a limit aborted with "memory allocation …
/// failed". A 3,500² image's render buffers (~1.5 GB) fit a 2.5 GB limit, the bench's
/// (~2.9 GB) do not: one line before the table and any render.
#[cfg(unix)]
#[test]
fn bench_render_checks_its_memory() {
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v 2500000 && exec '{}' bench render --size 3500 --spp 2 --k 1",
            env!("CARGO_BIN_EXE_stcvae")
        ))
        .current_dir(root())
        .output()
        .unwrap();
    let e = fails(&out);
    assert!(
        e.contains("--size 3500: a 3500 x 3500 image needs about")
            && !e.contains("memory allocation")
            && e.lines().filter(|l| l.starts_with("error")).count() == 1,
        "{e}"
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(!text.contains("sigma_t"), "{text}");
}

/// On a software adapter the path state lives in host memory, which `render` checks with
/// the image: `bench devices` did not, and a 3,000² bench under a 3 GB limit aborted with
/// "memory allocation of 108000000 bytes failed". Now a one-line error before any row.
/// (A hardware adapter keeps that state on the device: skipped there.)
#[cfg(unix)]
#[test]
fn bench_devices_checks_the_software_gpus_memory() {
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v 3000000 && exec '{}' bench devices --scene configs/scenes/sphere.toml \
             --size 3000 --spp 1 --k 1",
            env!("CARGO_BIN_EXE_stcvae")
        ))
        .env("WGPU_BACKEND", "vulkan")
        .current_dir(root())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    if err.contains("no wgpu adapter") && std::env::var_os("CI").is_none() {
        common::skip(&format!(
            "bench_devices_checks_the_software_gpus_memory: {err}"
        ));
        return;
    }
    // Skipped only where the banner names a hardware adapter. Any other outcome (no banner,
    // a load error, the adapter failing under the ulimit) reaches the assertions, so the
    // test cannot pass in CI without the check having run.
    let gpu = text.lines().find(|l| l.trim_start().starts_with("gpu: "));
    if let Some(line) = gpu
        && !line.contains("Cpu")
    {
        common::skip(&format!(
            "bench_devices_checks_the_software_gpus_memory: a hardware adapter ({})",
            line.trim()
        ));
        return;
    }
    let e = fails(&out);
    assert!(
        e.contains("--size 3000: a 3000 x 3000 image needs about")
            && e.contains("(with the software GPU's path state)")
            && !e.contains("memory allocation")
            && e.lines().filter(|l| l.starts_with("error")).count() == 1,
        "{e}"
    );
    assert!(!text.lines().any(|l| l.contains(" PT ")), "{text}");
}

/// `bench devices`' table: a row per density and integrator, each with both devices'
/// times and paths/s, and a GPU/CPU ratio that is the GPU's paths/s over the CPU's; every
/// render is of the bench's image (`--size`, both sides), so each device's rate times its
/// time is that image's paths.
#[test]
fn bench_devices_prints_both_devices_and_their_ratio() {
    let Some(out) = on_vulkan(
        &[
            "bench",
            "devices",
            "--scene",
            "configs/scenes/sphere.toml",
            "--size",
            "16",
            "--spp",
            "2",
            "--k",
            "1,2",
        ],
        "bench_devices_prints_both_devices_and_their_ratio",
    ) else {
        return;
    };
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        text.contains("\n  gpu: ") && text.contains("\n  cpu ("),
        "{text}"
    );
    let rows: Vec<Vec<&str>> = text
        .lines()
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        .filter(|w| w.len() > 2 && (w[1] == "PT" || w[1] == "ST-CVAE"))
        .collect();
    let labels: Vec<(&str, &str)> = rows.iter().map(|w| (w[0], w[1])).collect();
    assert_eq!(
        labels,
        [("1", "PT"), ("1", "ST-CVAE"), ("2", "PT"), ("2", "ST-CVAE")],
        "{text}"
    );
    let number = |f: &str| -> f64 {
        f.trim_end_matches('x')
            .parse()
            .unwrap_or_else(|_| panic!("{f}: {text}"))
    };
    for w in &rows {
        // The ratio is the one field ending in "x".
        let ratio: Vec<f64> = w
            .iter()
            .filter_map(|f| f.strip_suffix('x')?.parse().ok())
            .collect();
        assert!(
            ratio.len() == 1 && ratio[0].is_finite() && ratio[0] > 0.0,
            "{text}"
        );
        // k, integrator, CPU s, GPU s (four significant digits: 5e-4 of each at most),
        // then CPU's and GPU's paths/s, each a number with two decimals and, from 1,000
        // on, a unit (`progress::si`), then the ratio.
        let at_ratio = w.iter().position(|f| f.ends_with('x')).unwrap();
        let rates = printed_rates(&w[4..at_ratio], &text);
        assert_eq!(rates.len(), 2, "{text}");
        let [(cpu, cpu_half), (gpu, gpu_half)] = [rates[0], rates[1]];
        // The ratio is the GPU's paths/s over the CPU's, not its inverse (which a ratio
        // within the rounding of 1 on all four rows alone could pass). Allowed: its two
        // printed decimals, and twice the rates' relative rounding.
        let expected = gpu / cpu;
        assert!(
            (ratio[0] - expected).abs()
                <= 0.006 + 2.0 * expected * (cpu_half / cpu + gpu_half / gpu),
            "GPU/CPU {} where the rates give {expected}: {text}",
            ratio[0]
        );
        // Each device rendered the bench's image, 16² pixels at 2 spp: its rate times its
        // time is 512 paths (not a scene's own 128² camera left in one dimension), within
        // twice the rounding of both.
        let (cpu_s, gpu_s) = (number(w[2]), number(w[3]));
        for (rate, half, seconds) in [(cpu, cpu_half, cpu_s), (gpu, gpu_half, gpu_s)] {
            assert!(
                (rate * seconds / 512.0 - 1.0).abs() <= 2.0 * (half / rate + 5e-4),
                "{rate} paths/s for {seconds} s are not 512 paths: {text}"
            );
        }
    }
}

/// `bench render`'s table on each device: a row per ladder step, the device in the header,
/// and columns that agree with each other (the speed-up is PT's time over ST-CVAE's, the
/// equal-error figure the speed-up times the variance ratio, and the paths/s their
/// inverse ratio: both render the same paths). Tolerances: the printed rounding (two
/// decimals, four significant digits).
#[test]
fn bench_render_prints_the_ladder_on_each_device() {
    for device in ["cpu", "gpu"] {
        let args = [
            "bench", "render", "--device", device, "--k", "0.25,0.5", "--spp", "6", "--size", "8",
        ];
        let out = if device == "cpu" {
            stcvae(&args)
        } else {
            match on_vulkan_any(&args, &[], "bench_render_prints_the_ladder_on_each_device") {
                Some(out) => out,
                None => return,
            }
        };
        ok(&out);
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        let header = text.lines().next().unwrap_or_default();
        assert!(header.contains(&format!("), {device}")), "{text}");
        let number = |w: &str| -> f64 {
            w.trim_end_matches('x')
                .parse()
                .unwrap_or_else(|_| panic!("{w}: {text}"))
        };
        let rows: Vec<Vec<&str>> = text
            .lines()
            .map(|l| l.split_whitespace().collect::<Vec<_>>())
            .filter(|w| w.len() >= 15 && w[1].starts_with('('))
            .collect();
        let labels: Vec<&str> = rows.iter().map(|w| w[0]).collect();
        assert_eq!(labels, ["0.25", "0.5"], "{text}");
        for w in &rows {
            // k, σ_t (three fields), PT s, ST s, speed-up, var ratio, equal-error, three
            // work columns, bias, its bound, noise, then PT's and ST-CVAE's paths/s, each a
            // number with two decimals and a unit (none below 1,000: `progress::si`).
            let (pt_s, st_s) = (number(w[4]), number(w[5]));
            let (speed_up, var_ratio, equal) = (number(w[6]), number(w[7]), number(w[8]));
            assert!(w[6].ends_with('x') && w[8].ends_with('x'), "{text}");
            assert!(pt_s > 0.0 && st_s > 0.0, "{text}");
            assert!(
                (speed_up - pt_s / st_s).abs() <= 0.006 + 0.002 * speed_up,
                "{text}"
            );
            assert!(
                (equal - speed_up * var_ratio).abs() <= 0.005 * (speed_up + var_ratio) + 0.006,
                "{text}"
            );
            let rates = printed_rates(&w[15..], &text);
            assert_eq!(rates.len(), 2, "{text}");
            let [(pt_rate, pt_half), (st_rate, st_half)] = [rates[0], rates[1]];
            // Both render the same paths: PT's rate over ST-CVAE's is ST's time over PT's.
            // Allowed: each rate's printed rounding, the times' (four significant digits,
            // 5e-4 each) and as much again.
            let allowed = 2.0 * (pt_half / pt_rate + st_half / st_rate + 1e-3);
            assert!(
                (pt_rate * pt_s / (st_rate * st_s) - 1.0).abs() <= allowed,
                "{text}"
            );
        }
    }
}

/// The numbers of `bench error`'s row for the image `path` in its printed table `text`.
fn bench_error_row(text: &str, path: &str) -> Vec<f64> {
    let line = text
        .lines()
        .find(|l| l.starts_with(path))
        .unwrap_or_else(|| panic!("no row for {path}: {text}"));
    line[path.len()..]
        .split([' ', ','])
        .filter_map(|w| w.parse().ok())
        .collect()
}

/// `bench error` on renders of the sphere: a 2-spp image has a larger error than a 32-spp
/// one against a reference of three 32-spp renders (the MSE falls as 1/spp, so the RMSEs
/// should differ by ~4×; asserting 2× leaves room for the noise of an MSE estimated from
/// 16²·3 = 768 heavy-tailed terms, ~15 % relative), the `vs first` column is the ratio of
/// the MSE·s column, and bad arguments are one-line errors naming the file or value.
#[test]
fn bench_error_ranks_renders_by_error_and_names_bad_inputs() {
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 16);
    let render = |name: &str, spp: &str, seed: &str, scene: &Path| {
        let out = d.path().join(name);
        ok(&render_scene(
            scene,
            "pt",
            spp,
            seed,
            &out,
            &["--device", "cpu"],
        ));
        out.with_extension("exr").to_str().unwrap().to_string()
    };
    let refs: Vec<String> = ["1", "2", "3"]
        .iter()
        .map(|s| render(&format!("ref{s}"), "32", s, &scene))
        .collect();
    let low = render("low", "2", "10", &scene);
    let high = render("high", "32", "11", &scene);
    let reference = refs.join(",");
    // `stcvae bench error --reference <the three refs> ARGS...`
    let bench_error = |args: &[&str]| {
        let mut all = vec!["bench", "error", "--reference", &reference];
        all.extend_from_slice(args);
        stcvae(&all)
    };
    let out = bench_error(&[&format!("{high}:2"), &format!("{low}:0.5")]);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(text.contains("mean of 3 render(s), 16x16"), "{text}");
    let row = |path: &str| bench_error_row(&text, path);
    // seconds, RMSE, MSE·s, vs first, then the three object ratios.
    let (h, l) = (row(&high), row(&low));
    assert_eq!(h.len(), 7, "{text}");
    assert_eq!(l.len(), 7, "{text}");
    assert!(
        l[1] > 2.0 * h[1],
        "RMSE at 2 spp {} vs 32 spp {}",
        l[1],
        h[1]
    );
    assert_eq!(h[3], 1.0);
    assert!((l[3] - l[2] / h[2]).abs() <= 0.01 * l[3] + 0.01, "{text}");
    // The figures themselves, recomputed from the EXRs: MSE = mean((image − reference)²) −
    // mean(Var(reference mean)) (the three renders' sample variance over 3), raised to 0;
    // the RMSE column is its root, printed to 4 decimals (±5e-5), and MSE·s the MSE times
    // the seconds, to 4 significant digits (±5e-4 relative). Both stay within those with
    // 1e-5 and 5e-4 to spare (the sums are the binary's, in the same order). With an MSE
    // in (1e-6, 0.5) (here ~0.002 and ~0.07), its root differs from it by over 9e-4 and
    // 41 %: an RMSE column that printed the MSE, or an MSE·s made of the RMSE, fails.
    let pixels = |p: &str| {
        render_gpu::image_io::read_exr(Path::new(p))
            .unwrap()
            .0
            .pixels
    };
    let ref_pixels: Vec<Vec<[f32; 3]>> = refs.iter().map(|r| pixels(r)).collect();
    let mse_of = |p: &str| -> f64 {
        let img = pixels(p);
        let (mut d2, mut noise) = (0.0f64, 0.0f64);
        for (i, px) in img.iter().enumerate() {
            for c in 0..3 {
                let v: Vec<f64> = ref_pixels.iter().map(|r| f64::from(r[i][c])).collect();
                let m = v.iter().sum::<f64>() / 3.0;
                d2 += (f64::from(px[c]) - m).powi(2);
                noise += v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / 2.0 / 3.0;
            }
        }
        ((d2 - noise) / (3 * img.len()) as f64).max(0.0)
    };
    for (got, path, seconds) in [(&h, &high, 2.0), (&l, &low, 0.5)] {
        let mse = mse_of(path);
        assert!(mse > 1e-6 && mse < 0.5, "{path}: MSE {mse}: {text}");
        assert!(
            (got[1] - mse.sqrt()).abs() <= 6e-5,
            "{path}: RMSE {} against √{mse}: {text}",
            got[1]
        );
        assert!(
            (got[2] - mse * seconds).abs() <= 1e-3 * mse * seconds,
            "{path}: MSE·s {} against {}: {text}",
            got[2],
            mse * seconds
        );
    }
    // A threshold that every pixel, the sky's too, exceeds, or that none does, is said so:
    // the object column then measures the whole frame, or nothing. This scene's sky
    // (0.1 a channel, seen as R + G + B ≈ 0.29) is above the default 0.2.
    let all = ok(&out);
    assert!(
        all.contains("note: every pixel's R + G + B exceeds --object-threshold 0.2"),
        "{all}"
    );
    let with_threshold = |t: &str| {
        ok(&bench_error(&[
            "--object-threshold",
            t,
            &format!("{high}:2"),
        ]))
    };
    let none = with_threshold("1000");
    assert!(
        none.contains("note: no pixel's R + G + B exceeds --object-threshold 1000"),
        "{none}"
    );
    let split = with_threshold("0.5");
    assert!(!split.contains("note:"), "{split}");
    // An image rendered with a reference's seed shares its samples (it read RMSE 0): refused
    // by the EXRs' tags, naming both files and the seed.
    let twin = render("twin", "64", "1", &scene);
    let e = fails(&bench_error(&[&format!("{twin}:1")]));
    assert!(
        e.contains("seed 1 in common") && e.contains("ref1.exr") && e.contains("twin.exr"),
        "{e}"
    );
    // So is one by the other integrator: its hash differs (the integrator is in it), yet
    // with a reference's seed it draws the same camera rays and first numbers.
    let st_twin = d.path().join("st_twin");
    ok(&render_scene(
        &scene,
        "stcvae",
        "4",
        "2",
        &st_twin,
        &["--device", "cpu"],
    ));
    let st_twin = st_twin.with_extension("exr");
    let e = fails(&bench_error(&[&format!("{}:1", st_twin.display())]));
    assert!(
        e.contains("seed 2 in common") && e.contains("ref2.exr") && e.contains("st_twin.exr"),
        "{e}"
    );
    // `render --variance`'s side image is no render (it was measured as one).
    let varied = d.path().join("varied");
    ok(&render_scene(
        &scene,
        "pt",
        "8",
        "12",
        &varied,
        &["--device", "cpu", "--variance"],
    ));
    let var_image = d.path().join("varied.var.exr");
    assert!(var_image.is_file());
    let e = fails(&bench_error(&[&format!("{}:8", var_image.display())]));
    assert!(
        e.contains("varied.var.exr: a variance image of `render --variance`"),
        "{e}"
    );
    // A copy of a reference without its tag (as another renderer's EXR would be) is told
    // apart by its pixels instead.
    let (pixels, _) = render_gpu::image_io::read_exr(Path::new(&refs[1])).unwrap();
    let copy = d.path().join("copy.exr");
    std::fs::write(
        &copy,
        render_gpu::image_io::encode_untagged_exr(&pixels).unwrap(),
    )
    .unwrap();
    let e = fails(&bench_error(&[&format!("{}:1", copy.display())]));
    assert!(
        e.contains("same pixels") && e.contains("ref2.exr") && e.contains("copy.exr"),
        "{e}"
    );
    // A tagged render with a negative pixel is damaged (stcvae's pixels are ≥ 0), as
    // `merge` says too; it was measured without a word.
    let (mut img, tag) = render_gpu::image_io::read_exr(Path::new(&high)).unwrap();
    img.pixels[5][0] = -1.0;
    let tag = render_gpu::image_io::RenderTag {
        seeds: vec![77],
        ..tag.unwrap()
    };
    let neg = d.path().join("neg.exr");
    std::fs::write(&neg, render_gpu::image_io::encode_exr(&img, &tag).unwrap()).unwrap();
    let e = fails(&bench_error(&[&format!("{}:1", neg.display())]));
    assert!(e.contains("neg.exr: pixel (5, 0) is -1"), "{e}");
    let e = fails(&bench_error(&[&format!("{high}:abc")]));
    assert!(
        e.contains("`abc` after the ':' is not a number of seconds"),
        "{e}"
    );

    // `vs first` divides by the first timed image's MSE·s in every row, not by the row
    // above's: here high's (~0.0045), where low's at 100 s (~6.8) would give ~0.004 for
    // the third row instead of ~5.9.
    let other = render("other", "4", "12", &scene);
    let out = bench_error(&[
        &format!("{high}:2"),
        &format!("{low}:100"),
        &format!("{other}:1"),
    ]);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    let row_of = |path: &str| bench_error_row(&text, path);
    let (first, third) = (row_of(&high), row_of(&other));
    assert!(
        (third[3] - third[2] / first[2]).abs() <= 0.01 * third[3] + 0.01,
        "{text}"
    );

    // --plot: labelled images share a line. "PT" (the first line, black like the axes)
    // joins two points; "other" (the second, red) has one; a third line would be blue.
    let plot = d.path().join("error.png");
    let plot_of = |images: &[&str]| {
        let mut args = vec!["--plot", plot.to_str().unwrap()];
        args.extend_from_slice(images);
        bench_error(&args)
    };
    let out = plot_of(&[
        &format!("PT={low}:0.5"),
        &format!("PT={high}:2"),
        &format!("other={other}:1"),
    ]);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(text.contains("plot: "), "{text}");
    // The table names each image by its file, not its label.
    assert!(text.lines().any(|l| l.starts_with(&other)), "{text}");
    let (width, height, buf) = common::read_png(&plot);
    assert_eq!((width, height), (900, 600));
    let count = |rgb: [u8; 3]| buf.chunks(3).filter(|p| *p == rgb).count();
    // The legend's red sample is ~38 pixels and the marker's disc ~50.
    assert!(count([255, 0, 0]) > 60, "no red marker drawn");
    assert_eq!(
        count([0, 0, 255]),
        0,
        "a third (blue) line: the labels were not shared"
    );
    // Without any seconds there is no x axis: said before anything is printed.
    let out = plot_of(&[&high]);
    let e = fails(&out);
    assert!(e.contains("no image has :SECONDS"), "{e}");
    assert!(out.stdout.is_empty(), "half a table printed");

    let small_scene = d.path().join("small.toml");
    std::fs::write(&small_scene, sphere_scene_text(8)).unwrap();
    let small = render("small", "1", "1", &small_scene);
    // A bad image after a good one: refused before any row is printed.
    let out = bench_error(&[&high, &small]);
    let e = fails(&out);
    assert!(
        e.contains(&small) && e.contains("8x8") && e.contains("16x16"),
        "{e}"
    );
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(out.stdout.is_empty(), "half a table printed");
    // The same render twice (as two references, or as a reference and an image) is not
    // independent of itself.
    let twice = format!("{},{}", refs[0], refs[0]);
    let e = fails(&stcvae(&["bench", "error", "--reference", &twice, &high]));
    assert!(e.contains("same file"), "{e}");
    let e = fails(&bench_error(&[&refs[1]]));
    assert!(e.contains("same file"), "{e}");
    let missing = d.path().join("none.exr");
    let e = fails(&bench_error(&[missing.to_str().unwrap()]));
    assert!(e.contains("none.exr"), "{e}");
    let e = fails(&bench_error(&[&format!("{low},{high}")]));
    assert!(e.contains("three (R,G,B"), "{e}");
    // References of two scenes (here twice the density) are not one reference: their
    // difference counted as its noise and was subtracted from every image's error.
    let dense_scene = d.path().join("dense.toml");
    std::fs::write(
        &dense_scene,
        sphere_scene_text(16).replace(
            "sigma_t = [20.0, 20.0, 20.0]",
            "sigma_t = [40.0, 40.0, 40.0]",
        ),
    )
    .unwrap();
    let dense = render("dense", "32", "4", &dense_scene);
    let mixed = format!("{},{dense}", refs[0]);
    let e = fails(&stcvae(&["bench", "error", "--reference", &mixed, &high]));
    assert!(
        e.contains("different scenes") && e.contains("dense.exr"),
        "{e}"
    );
    // An image of another scene than the references' (of the same size) is refused by the
    // view hashes in the tags, naming both files; it was measured as a large error. An
    // ST-CVAE image of the references' own scene shows the same view, whatever its
    // integrator and settings.
    let e = fails(&bench_error(&[&format!("{dense}:1")]));
    assert!(
        e.contains("show different scenes") && e.contains("ref1.exr") && e.contains("dense.exr"),
        "{e}"
    );
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    let st = d.path().join("st");
    ok(&render_scene(
        &scene,
        "stcvae",
        "4",
        "13",
        &st,
        &["--device", "cpu", "--nee", "false"],
    ));
    ok(&bench_error(&[&format!(
        "{}:1",
        st.with_extension("exr").display()
    )]));
    // A channel the reference leaves black on the object has no ratio: n/a, not NaN.
    let red_scene = d.path().join("red.toml");
    let red_text = sphere_scene_text(16)
        .replace(
            "irradiance = [2.0, 2.0, 2.0]",
            "irradiance = [2.0, 0.0, 0.0]",
        )
        .replace("radiance = [0.1, 0.1, 0.1]", "radiance = [0.1, 0.0, 0.0]");
    assert!(red_text.contains("[2.0, 0.0, 0.0]") && red_text.contains("[0.1, 0.0, 0.0]"));
    std::fs::write(&red_scene, red_text).unwrap();
    let red: Vec<String> = ["5", "6"]
        .iter()
        .map(|s| render(&format!("red{s}"), "8", s, &red_scene))
        .collect();
    let red_img = render("red7", "8", "7", &red_scene);
    let out = stcvae(&[
        "bench",
        "error",
        "--reference",
        &red.join(","),
        &format!("{red_img}:1"),
    ]);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("n/a, n/a") && !text.contains("NaN"), "{text}");
}

/// The paths/s figures among a bench row's `fields` (each printed with two decimals and,
/// from 1,000 on, a unit: `progress::si`), each with half its last printed digit, so that
/// a test can allow for the rounding: (rate, half a digit). `text` is the whole output,
/// shown where a field is no number.
fn printed_rates(fields: &[&str], text: &str) -> Vec<(f64, f64)> {
    let mut rates: Vec<(f64, f64)> = Vec::new();
    for f in fields {
        let scale = match *f {
            "k" => 1e3,
            "M" => 1e6,
            "G" => 1e9,
            _ => {
                let rate = f.parse().unwrap_or_else(|_| panic!("{f}: {text}"));
                rates.push((rate, 0.005));
                continue;
            }
        };
        let last = rates.last_mut().expect("a unit after its number");
        *last = (last.0 * scale, last.1 * scale);
    }
    rates
}
