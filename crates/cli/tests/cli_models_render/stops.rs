//! Renders stopped part way, by a signal or a time budget: what they keep, what they
//! say, and their exit codes.

use super::*;

/// Ctrl-C during a render keeps the passes finished: exit status 130, the image written
/// with the samples it has, and its JSON says it was cut short (`interrupted`, `spp` below
/// `spp_requested`, the same spp as the EXR's tag). The signal goes out once the progress
/// lines (written per update under STCVAE_LOG_PROGRESS_EVERY=0) count two passes' samples,
/// so at least one pass has finished however slow the machine.
#[cfg(unix)]
#[test]
fn an_interrupted_render_keeps_its_finished_passes_and_says_so() {
    interrupt_a_render(libc::SIGINT, "SIGINT");
}

/// SIGTERM (`kill`, a batch scheduler's time limit) stops a render as Ctrl-C does, and
/// the exit status says which: 143 = 128 + 15, as a shell reports for a process the signal
/// ended (it was 130, Ctrl-C's, since one handler took all stop signals).
#[cfg(unix)]
#[test]
fn a_terminated_render_keeps_its_passes_and_exits_143() {
    interrupt_a_render(libc::SIGTERM, "SIGTERM");
}

/// SIGHUP (the terminal closed) stops a render as Ctrl-C does, and the exit status and the
/// message say which: 129 = 128 + 1. No other test sends it unignored (the render under
/// `nohup` below must not stop for it), so a stop-signal list without it, whose stop would
/// then read as Ctrl-C's (130, no name), went unseen.
#[cfg(unix)]
#[test]
fn a_hung_up_render_keeps_its_passes_and_exits_129() {
    interrupt_a_render(libc::SIGHUP, "SIGHUP");
}

/// The samples of one pass of [`logged_pt_render`]: 256 spp of the 16² pixels (100,000 spp
/// takes the largest pass).
#[cfg(unix)]
const PASS: u64 = 256 * 16 * 16;

/// A PT render on the CPU of a 16² sphere in `dir` at 100,000 spp, writing a progress line
/// per update (STCVAE_LOG_PROGRESS_EVERY=0) to a piped stderr; and its output stem.
#[cfg(unix)]
fn logged_pt_render(dir: &Path) -> (Command, PathBuf) {
    let scene = sphere_scene_file(dir, 16);
    let out = dir.join("r");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_stcvae"));
    cmd.args([
        "render",
        "--device",
        "cpu",
        "--integrator",
        "pt",
        "--spp",
        "100000",
    ])
    .arg("--scene")
    .arg(&scene)
    .arg("--out")
    .arg(&out)
    .env("STCVAE_LOG_PROGRESS_EVERY", "0")
    .stderr(std::process::Stdio::piped());
    (cmd, out)
}

/// Reads a render's stderr (progress lines written per update under
/// STCVAE_LOG_PROGRESS_EVERY=0) to its end, sending each signal once a line counts at least
/// its number of samples done, in order; returns the text, every signal having been sent.
#[cfg(unix)]
fn signal_after_samples(child: &mut std::process::Child, signals: &[(libc::c_int, u64)]) -> String {
    use std::io::BufRead;
    let mut err = String::new();
    let mut sent = 0;
    for line in std::io::BufReader::new(child.stderr.take().unwrap()).lines() {
        let line = line.unwrap();
        let done = line
            .split_whitespace()
            .find_map(|w| w.split_once('/'))
            .and_then(|(n, _)| n.replace(',', "").parse::<u64>().ok());
        while let Some(&(signal, samples)) = signals.get(sent)
            && done.is_some_and(|n| n >= samples)
        {
            // SAFETY: a plain system call on a child this test owns and has not reaped.
            assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, signal) }, 0);
            sent += 1;
        }
        err += &line;
        err.push('\n');
    }
    assert_eq!(
        sent,
        signals.len(),
        "a signal was not sent ({signals:?}): {err}"
    );
    err
}

/// A SIGHUP the render was started with ignored (`nohup`) stays ignored: ctrlc's handler,
/// installed over the ignoring, stopped it when the terminal closed. SIGHUP goes out at
/// the first samples counted and SIGTERM once two passes are done: the stop must be
/// SIGTERM's (exit 143), which it cannot be if SIGHUP was taken (129), nor if the render
/// ended before either signal reached it.
#[cfg(unix)]
#[test]
fn an_ignored_hangup_is_still_ignored() {
    use std::os::unix::process::CommandExt;
    let d = tempfile::tempdir().unwrap();
    let (mut cmd, out) = logged_pt_render(d.path());
    // SAFETY: between fork and exec only `signal`, which is async-signal-safe.
    unsafe {
        cmd.pre_exec(|| {
            libc::signal(libc::SIGHUP, libc::SIG_IGN);
            Ok(())
        });
    }
    let mut child = cmd.spawn().unwrap();
    let err = signal_after_samples(&mut child, &[(libc::SIGHUP, 1), (libc::SIGTERM, 2 * PASS)]);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(143), "{err}");
    assert!(err.contains("interrupt (SIGTERM): stopping"), "{err}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
            .unwrap();
    assert_eq!(json["interrupted"], true, "{json}");
}

/// Stops a render with `signal` after two passes and checks what it kept (the tests above).
#[cfg(unix)]
fn interrupt_a_render(signal: libc::c_int, name: &str) {
    use std::os::unix::process::CommandExt;
    let d = tempfile::tempdir().unwrap();
    let (mut cmd, out) = logged_pt_render(d.path());
    // SIGHUP at its default, as in a terminal: a suite run under `nohup` would pass it on
    // ignored, and the render keeps it so (an_ignored_hangup_is_still_ignored).
    // SAFETY: between fork and exec only `signal`, which is async-signal-safe.
    unsafe {
        cmd.pre_exec(|| {
            libc::signal(libc::SIGHUP, libc::SIG_DFL);
            Ok(())
        });
    }
    let mut child = cmd.spawn().unwrap();
    let err = signal_after_samples(&mut child, &[(signal, 2 * PASS)]);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(128 + signal), "{err}");
    assert!(
        err.contains(&format!("interrupt ({name}): stopping")),
        "{err}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
            .unwrap();
    assert_eq!(json["interrupted"], true, "{json}");
    assert_eq!(json["spp_requested"], 100000, "{json}");
    let spp = json["spp"].as_u64().unwrap();
    assert!(
        (256..100000).contains(&spp) && spp.is_multiple_of(256),
        "{json}"
    );
    let (_, tag) = render_gpu::image_io::read_exr(&out.with_extension("exr")).unwrap();
    assert_eq!(tag.unwrap().spp, spp);
}

/// A time budget shorter than any pass stops after the first pass, which renders one
/// sample per pixel (render.rs): the JSON and the EXR's tag say 1 of the 64 asked, the
/// image is finite, and `merge` weighs two such renders as 2 spp; without --spp the
/// scene's spp is no limit. Nothing here depends on
/// how fast the machine is: every pass outlasts 10⁻⁹ s.
#[test]
fn a_time_budget_stops_after_a_pass_and_records_its_spp() {
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 16);
    let (a, b) = (d.path().join("a"), d.path().join("b"));
    for (out, seed) in [(&a, "1"), (&b, "2")] {
        let budget = ["--time-budget", "1e-9", "--device", "cpu"];
        ok(&render_scene(&scene, "pt", "64", seed, out, &budget));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
                .unwrap();
        assert_eq!(
            (json["spp"].as_u64(), json["spp_requested"].as_u64()),
            (Some(1), Some(64))
        );
        let (image, tag) = render_gpu::image_io::read_exr(&out.with_extension("exr")).unwrap();
        assert_eq!(tag.unwrap().spp, 1);
        assert!(image.pixels.iter().flatten().all(|v| v.is_finite()));
    }
    let m = d.path().join("m");
    ok(&merge_renders(&a, &b, &m));
    let (_, tag) = render_gpu::image_io::read_exr(&m.with_extension("exr")).unwrap();
    assert_eq!(tag.unwrap().spp, 2);
    // A budget without --spp is not stopped by the scene's spp (64): no limit is recorded
    // and the start line says so (the spp a budget reaches depends on the machine).
    let c = d.path().join("c");
    let out = stcvae(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--time-budget",
        "1e-9",
        "--device",
        "cpu",
        "--out",
        c.to_str().unwrap(),
    ]);
    ok(&out);
    assert!(
        String::from_utf8_lossy(&out.stderr).contains(" s, no spp limit"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(c.with_extension("json")).unwrap()).unwrap();
    assert_eq!(
        (json["spp"].as_u64(), json["spp_requested"].is_null()),
        (Some(1), true)
    );
    // 1e-9 s is far below a pass: the note says why the render took longer.
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("it stops only after a whole pass (the first is 1 spp)"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The GPU's time budget (lavapipe in CI): its first chunk renders one sample for each
/// of a pixel's path slots (times STCVAE_GPU_LANE_SAMPLES where set), so a budget shorter
/// than that chunk gets that chunk whole, recorded as its spp in the JSON and the EXR
/// alike, and the note says why it took longer than asked. Skipped, with the reason, only where no Vulkan adapter exists and
/// not under CI.
#[test]
fn a_gpu_time_budget_renders_whole_chunks() {
    let d = tempfile::tempdir().unwrap();
    let scene = sphere_scene_file(d.path(), 16);
    let out = d.path().join("g");
    let args = [
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--integrator",
        "pt",
        "--spp",
        "64",
        "--time-budget",
        "1e-9",
        "--device",
        "gpu",
        "--out",
        out.to_str().unwrap(),
    ];
    let Some(o) = on_vulkan(&args, "a_gpu_time_budget_renders_whole_chunks") else {
        return;
    };
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
            .unwrap();
    let first = json["gpu_dispatch"]["first_chunk_spp"].as_u64().unwrap();
    assert!((1..=64).contains(&first), "{json}");
    // The first chunk, then the budget is spent.
    assert_eq!(json["spp"].as_u64(), Some(first), "{json}");
    assert_eq!(json["spp_requested"].as_u64(), Some(64), "{json}");
    assert_eq!(json["interrupted"], false, "{json}");
    let (image, tag) = render_gpu::image_io::read_exr(&out.with_extension("exr")).unwrap();
    assert_eq!(tag.unwrap().spp, first);
    assert!(image.pixels.iter().flatten().all(|v| v.is_finite()));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(&format!(
            "(the GPU's first renders {first} spp here, one sample per path slot"
        )),
        "{err}"
    );
}
